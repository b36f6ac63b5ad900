// The real ioportd against the real simulator on ptys, through a real Modbus client (libmodbus),
// row by row of ../shared/spec/gateway.md.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include "tests/support/gateway.hpp"
#include "tests/support/process.hpp"

namespace ioport::test {
namespace {

constexpr int device_failure = 0x04;
constexpr int path_unavailable = 0x0A;
constexpr int target_failed = 0x0B;

const std::string hub_modules = "dim16:0,dom16:0,dom16:1,acm3p:0,lim16:0,rgbdm:0,mux8m:0,dccim:0";

// The links' timeouts are wide: nothing here is about them, and on a machine whose cores are
// busy (scripts/test --under-load) the simulator answered later than 30 ms, so that a module
// meant to refuse a write was found silent instead.
std::string gateway_yaml(const std::string& hub_link, const std::string& id2_link,
                         const std::string& modbus_extra = "") {
    return fmt::format(R"(modbus:
  listen: "127.0.0.1:0"
{}
links:
  - name: hub0
    protocol: ioport
    device: {}
    unit_id: 1
    timeout: 250ms
    retries: 1
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0, initial: 0x00F0, refresh: 1s }}
      - {{ type: dom16, number: 1 }}
      - {{ type: acm3p, number: 0 }}
      - {{ type: lim16, number: 0 }}
      - {{ type: rgbdm, number: 0, initial: green }}
      - {{ type: mux8m, number: 0, initial: 0x0707 }}
      - {{ type: dccim, number: 0 }}
  - name: press
    protocol: id2
    device: {}
    unit_id: 2
    timeout: 500ms
)",
                       modbus_extra, hub_link, id2_link);
}

class GatewayTest : public ::testing::Test {
  protected:
    explicit GatewayTest(const std::string& modbus_extra = "")
        : gateway(gateway_yaml(hub.link(), id2.link(), modbus_extra)) {}

    // Waits until the module's status register (1100 + slot) reads `status`.
    bool status_becomes(ModbusClient& client, int slot, int status,
                        std::chrono::milliseconds deadline = 5s) {
        return eventually(
            [&] {
                const auto value = client.read_input_registers(1100 + slot, 1);
                return value && (*value)[0] == status;
            },
            deadline);
    }
    bool all_online(ModbusClient& client) {
        return eventually([&] {
            const auto state = client.read_input_registers(1000, 1);
            return state && (*state)[0] == 1;
        });
    }
    std::string sim_value(SimProcess& sim, const std::string& module) {
        auto text = sim.ctl("get " + module);
        return text.substr(0, text.find('\n'));
    }

    SimProcess hub{"--hub", hub_modules, {"--no-line-timing"}};
    SimProcess id2{"--id2", "", {"--no-line-timing"}};
    GatewayProcess gateway;
};

TEST_F(GatewayTest, ReadsInputsThroughEveryTable) {
    hub.ctl("set dim16:0 0x8001");
    hub.ctl("set lim16:0 0x0102");
    hub.ctl("set acm3p:0 13208 41203 4095");
    ModbusClient client(gateway.port());
    ASSERT_TRUE(client.connected());
    ASSERT_TRUE(all_online(client));
    // The three modules are polled one after the other: wait until each was read once more.
    ASSERT_TRUE(eventually([&] {
        const auto dim = client.read_input_registers(0, 1);
        const auto lim = client.read_input_registers(8, 1);
        const auto acm = client.read_input_registers(16, 1);
        return dim && (*dim)[0] == 0x8001 && lim && (*lim)[0] == 0x0102 && acm &&
               (*acm)[0] == 13208;
    }));
    const auto inputs = client.read_discrete_inputs(0, 16);
    ASSERT_TRUE(inputs);
    EXPECT_EQ((*inputs)[0], 1);
    EXPECT_EQ((*inputs)[1], 0);
    EXPECT_EQ((*inputs)[15], 1);
    const auto lim = client.read_discrete_inputs(128, 16);
    ASSERT_TRUE(lim);
    EXPECT_EQ((*lim)[1], 1);
    EXPECT_EQ((*lim)[8], 1);
    EXPECT_EQ((*client.read_input_registers(8, 1))[0], 0x0102);
    const auto analog = client.read_input_registers(16, 3);
    ASSERT_TRUE(analog);
    EXPECT_EQ(*analog, (std::vector<std::uint16_t>{13208, 41203, 4095}));
    const auto percent = client.read_input_registers(200, 2);
    ASSERT_TRUE(percent);
    EXPECT_FLOAT_EQ(modbus_get_float_abcd(percent->data()),
                    static_cast<float>(13208 / 65535.0 * 100));
}

TEST_F(GatewayTest, WritesReachTheDeviceBeforeTheResponse) {
    ModbusClient client(gateway.port());
    ASSERT_TRUE(all_online(client));
    ASSERT_TRUE(client.write_register(0, 0x93D1));
    EXPECT_EQ(sim_value(hub, "dom16:0"), "37841");  // no waiting: acknowledged means applied
    const auto coils = client.read_coils(0, 16);
    ASSERT_TRUE(coils);
    EXPECT_EQ((*coils)[0], 1);
    EXPECT_EQ((*coils)[1], 0);
    EXPECT_EQ((*coils)[4], 1);
    ASSERT_TRUE(client.write_coil(1, true));
    EXPECT_EQ(sim_value(hub, "dom16:0"), "37843");
    EXPECT_EQ((*client.read_holding_registers(0, 1))[0], 0x93D3);
}

TEST_F(GatewayTest, InitialStatesAreSentAtStartUp) {
    ModbusClient client(gateway.port());
    ASSERT_TRUE(all_online(client));
    EXPECT_EQ(sim_value(hub, "dom16:0"), "240");
    EXPECT_EQ((*client.read_holding_registers(0, 1))[0], 0x00F0);
    EXPECT_EQ((*client.read_holding_registers(8, 1))[0], 2);  // green
    EXPECT_EQ((*client.read_holding_registers(16, 1))[0], 0x0707);
}

TEST_F(GatewayTest, UnknownUnitAnswers0A) {
    ModbusClient client(gateway.port(), 9);
    const auto value = client.read_input_registers(0, 1);
    ASSERT_FALSE(value);
    EXPECT_EQ(value.error(), path_unavailable);
}

TEST_F(GatewayTest, ErrorAckAnswers04AndKeepsTheConfirmedValue) {
    ModbusClient client(gateway.port());
    ASSERT_TRUE(all_online(client));
    ASSERT_TRUE(client.write_register(0, 0x0001));
    hub.ctl("fault dom16:0 error-ack");
    const auto written = client.write_register(0, 0x0002);
    ASSERT_FALSE(written);
    EXPECT_EQ(written.error(), device_failure);
    EXPECT_EQ(sim_value(hub, "dom16:0"), "1");
    hub.ctl("fault dom16:0 none");
    ASSERT_TRUE(status_becomes(client, 8, 1));
    EXPECT_EQ((*client.read_holding_registers(0, 1))[0], 0x0001);
}

TEST_F(GatewayTest, SilentModuleAnswers0B) {
    ModbusClient client(gateway.port());
    ASSERT_TRUE(all_online(client));
    hub.ctl("fault dim16:0 silent");
    ASSERT_TRUE(status_becomes(client, 0, 2));
    const auto read = client.read_input_registers(0, 1);
    ASSERT_FALSE(read);
    EXPECT_EQ(read.error(), target_failed);
    hub.ctl("fault dom16:1 silent");
    const auto write = client.write_register(1, 5);
    ASSERT_FALSE(write);
    EXPECT_EQ(write.error(), target_failed);
    // Diagnostics never raise 0B.
    EXPECT_TRUE(client.read_input_registers(1000, 10));
}

TEST_F(GatewayTest, UnplugAndReplugRestoresOutputs) {
    ModbusClient client(gateway.port());
    ASSERT_TRUE(all_online(client));
    ASSERT_TRUE(client.write_register(0, 0x1234));
    ASSERT_TRUE(client.write_register(8, 5));
    hub.ctl("unplug");
    ASSERT_TRUE(eventually([&] {
        const auto state = client.read_input_registers(1000, 1);
        return state && (*state)[0] == 0;
    }));
    const auto write = client.write_register(0, 1);
    ASSERT_FALSE(write);
    EXPECT_EQ(write.error(), target_failed);
    const auto read = client.read_input_registers(0, 1);
    ASSERT_FALSE(read);
    EXPECT_EQ(read.error(), target_failed);
    // A new pty: the outputs it comes back with are not what the clients were told.
    hub.ctl("set dom16:0 0");
    hub.ctl("set rgbdm:0 0");
    hub.ctl("replug");
    ASSERT_TRUE(all_online(client));
    EXPECT_EQ(sim_value(hub, "dom16:0"), "4660");
    EXPECT_EQ(sim_value(hub, "rgbdm:0").substr(0, 1), "5");
    const auto opens = client.read_input_registers(1008, 2);
    ASSERT_TRUE(opens);
    EXPECT_EQ((*opens)[1], 2);
}

TEST_F(GatewayTest, Id2UnitServesStopCounterAndReset) {
    id2.ctl("set stop 1");
    id2.ctl("set count 1234");
    ModbusClient client(gateway.port(), 2);
    ASSERT_TRUE(all_online(client));
    // Stop input and counter are polled one after the other: wait for both.
    ASSERT_TRUE(eventually([&] {
        const auto count = client.read_input_registers(0, 1);
        const auto stop = client.read_discrete_inputs(0, 1);
        return count && (*count)[0] == 1234 && stop && (*stop)[0] == 1;
    }));
    ASSERT_TRUE(client.write_coil(0, true));
    EXPECT_EQ(sim_value(id2, "count"), "0");
    EXPECT_EQ((*client.read_coils(0, 1))[0], 0);
    ASSERT_TRUE(client.write_coil(0, false));
}

TEST_F(GatewayTest, SigtermStopsWithin2s) {
    const auto started = std::chrono::steady_clock::now();
    EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0);
    EXPECT_LT(std::chrono::steady_clock::now() - started, 2s);
}

}  // namespace
}  // namespace ioport::test
