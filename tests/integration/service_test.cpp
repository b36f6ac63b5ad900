// ioportd's life as a service: systemd's protocol with a NOTIFY_SOCKET owned by the test (READY
// once started, STATUS kept current, WATCHDOG at a quarter of WatchdogSec and only while every
// link makes progress, RELOADING, STOPPING), SIGHUP reloads, and SIGTERM with a write in flight.
#include <bit>
#include <csignal>
#include <optional>

#include <gtest/gtest.h>

#include <fmt/format.h>

#include "tests/support/datagram_socket.hpp"
#include "tests/support/gateway.hpp"
#include "tests/support/process.hpp"
#include "tests/support/raw_client.hpp"

namespace ioport::test {
namespace {

using Clock = std::chrono::steady_clock;

// The receiving end of sd_notify: the daemon finds it in NOTIFY_SOCKET.
using NotifySocket = DatagramSocket;

// 250 ms: these tests are not about the link's timeout, and a busy machine's simulator answered
// a write later than 30 ms.
std::string hub_yaml(const std::string& device) {
    return fmt::format(R"(modbus: {{ listen: "127.0.0.1:0" }}
links:
  - {{ name: hub0, protocol: ioport, device: {}, timeout: 250ms,
      modules: [{{ type: dim16, number: 0 }}, {{ type: dom16, number: 0 }}] }}
)",
                       device);
}

TEST(ServiceNotify, ReadyStatusWatchdogAndStopping) {
    SimProcess hub("--hub", "dim16:0,dom16:0", {"--no-line-timing"});
    TempDir dir;
    NotifySocket notify(dir / "notify");
    GatewayProcess gateway(hub_yaml(hub.link()), {},
                           {"NOTIFY_SOCKET=" + notify.path(), "WATCHDOG_USEC=400000"});

    const auto ready = notify.wait_for("READY=1", 5s);
    ASSERT_FALSE(ready.empty()) << "no READY=1";
    // Sent after the listener is bound and the port was tried: the port is already open.
    EXPECT_NE(ready.find("STATUS=1 of 1 links up"), std::string::npos) << ready;

    // A quarter of WatchdogSec: about ten in a second; at least three leave room for a slow
    // machine, and none would mean the watchdog is never fed.
    int fed = 0;
    const auto second = Clock::now() + 1s;
    while (Clock::now() < second)
        if (notify.receive(second).find("WATCHDOG=1") != std::string::npos) ++fed;
    EXPECT_GE(fed, 3);

    EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0);
    EXPECT_FALSE(notify.wait_for("STOPPING=1", 1s).empty()) << "no STOPPING=1";
}

TEST(ServiceNotify, StatusFollowsTheLink) {
    SimProcess hub("--hub", "dim16:0,dom16:0", {"--no-line-timing"});
    TempDir dir;
    NotifySocket notify(dir / "notify");
    GatewayProcess gateway(hub_yaml(hub.link()), {}, {"NOTIFY_SOCKET=" + notify.path()});
    ASSERT_FALSE(notify.wait_for("READY=1", 5s).empty());
    hub.ctl("unplug");
    EXPECT_FALSE(notify.wait_for("STATUS=0 of 1 links up", 5s).empty());
    hub.ctl("replug");
    EXPECT_FALSE(notify.wait_for("STATUS=1 of 1 links up, 2 of 2 modules online", 5s).empty());
}

TEST(ServiceNotify, WithoutNotifySocketNothingChanges) {
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    GatewayProcess gateway(R"(modbus: { listen: "127.0.0.1:0" }
links: [{ name: hub0, protocol: ioport, device: )" +
                           hub.link() +
                           R"(, modules: [{ type: dim16, number: 0 }] }]
)");
    ModbusClient client(gateway.port());
    EXPECT_TRUE(client.read_input_registers(1000, 1));
    EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0);
}

TEST(Logging, TheConfiguredLogLevelAppliesAndTheCommandLineWins) {
    SimProcess hub("--hub", "dim16:0,dom16:0", {"--no-line-timing"});
    const auto yaml = hub_yaml(hub.link()) + "log_level: debug\n";
    const auto connect_and_stop = [](GatewayProcess& gateway) {
        {
            ModbusClient client(gateway.port());
            EXPECT_TRUE(client.read_input_registers(1000, 1));
        }
        EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0);
        return gateway.log();
    };
    GatewayProcess debug(yaml);
    EXPECT_NE(connect_and_stop(debug).find(" debug Modbus client 127.0.0.1:"), std::string::npos);
    GatewayProcess info(yaml, {"--log-level", "info"});
    const auto log = connect_and_stop(info);
    EXPECT_NE(log.find("ioportd stopped"), std::string::npos);
    EXPECT_EQ(log.find(" debug "), std::string::npos) << log;
}

// The largest timeout and retries the configuration allows, on lines that chatter or stay
// silent, with the WatchdogSec of the packaged unit: a step may take minutes there, and the
// daemon keeps feeding the watchdog through it, because the link acts at least once a timeout.
// (A stuck loop is caught one timeout and a second after its last act: link_watchdog_test.)
TEST(ServiceNotify, TheWatchdogIsFedThroughTheLongestStepsOfNoisyAndDeadLines) {
    SimProcess noisy("--hub", "dim16:0", {"--no-line-timing"});
    SimProcess noisy_fast("--hub", "dim16:0", {"--no-line-timing"});
    SimProcess dead("--hub", "dim16:0", {"--no-line-timing"});
    noisy.ctl("chatter 5ms");
    noisy_fast.ctl("chatter 5ms");
    dead.ctl("fault all silent");
    TempDir dir;
    NotifySocket notify(dir / "notify");
    const auto link = [](std::string_view name, const std::string& device,
                         std::string_view timeout) {
        return fmt::format(
            "  - {{ name: {}, protocol: ioport, device: {}, timeout: {}, retries: 10,\n"
            "      modules: [{{ type: dim16, number: 0 }}] }}\n",
            name, device, timeout);
    };
    // noisy_fast: the old bound of (retries + 1 + 10) timeouts + 1 s was 2.1 s; its steps take
    // 11 × 1.1 s. noisy: 11 × 110 s. dead: 11 × 10 s, with 10 s in which no byte moves.
    GatewayProcess gateway(
        "modbus: { listen: \"127.0.0.1:0\" }\nlinks:\n" + link("noisy", noisy.link(), "10s") +
            link("noisy_fast", noisy_fast.link(), "100ms") + link("dead", dead.link(), "10s"),
        {}, {"NOTIFY_SOCKET=" + notify.path(), "WATCHDOG_USEC=20000000"});
    ASSERT_FALSE(notify.wait_for("READY=1", 5s).empty());
    // A quarter of 20 s: every 5 s. Two of the dead line's silent timeouts pass in the window.
    const auto started = Clock::now();
    const auto end = started + 23s;
    std::vector<Clock::duration> gaps;
    auto last_fed = started;
    while (Clock::now() < end) {
        if (notify.receive(end).find("WATCHDOG=1") == std::string::npos) continue;
        gaps.push_back(Clock::now() - last_fed);
        last_fed = Clock::now();
    }
    gaps.push_back(end - last_fed);
    EXPECT_GE(gaps.size(), 5u);
    for (std::size_t i = 0; i < gaps.size(); ++i)
        EXPECT_LT(gaps[i], 7s)
            << "no WATCHDOG=1 for "
            << std::chrono::duration_cast<std::chrono::milliseconds>(gaps[i]).count()
            << " ms before notification " << i;
    // The lines were as the test says: the fast one's steps ended on a line that never went
    // quiet, and the daemon served Modbus all along.
    EXPECT_TRUE(gateway.wait_for_log("never stayed silent", 1s));
    for (int unit = 1; unit <= 3; ++unit) {
        ModbusClient client(gateway.port(), unit);
        EXPECT_TRUE(client.read_input_registers(1000, 10)) << "unit " << unit;
    }
    EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0);
}

// FC 06, holding register 0 (dom16 0) = 0x1234; its response is an echo.
const Bytes write_dom16 = {0x06, 0x00, 0x00, 0x12, 0x34};

std::string outputs_yaml(const std::string& device, std::string_view on_shutdown) {
    return fmt::format(R"(modbus: {{ listen: "127.0.0.1:0" }}
on_shutdown: {}
links:
  - {{ name: hub0, protocol: ioport, device: {}, timeout: 1s,
      modules: [{{ type: dom16, number: 0, initial: 0x00FF }}, {{ type: rgbdm, number: 0, initial: red }}] }}
)",
                       on_shutdown, device);
}

// SIGTERM while a write waits for the device's answer (delayed 300 ms): the write completes, its
// client gets the normal response, and the daemon exits 0 within 2 s.
void stop_with_a_write_in_flight(SimProcess& hub, GatewayProcess& gateway) {
    ModbusClient client(gateway.port());
    ASSERT_TRUE(eventually([&] {
        auto status = client.read_input_registers(1000, 1);
        return status && (*status)[0] == 1;  // every module online
    }));
    ASSERT_TRUE(client.write_register(8, 5));  // rgbdm 0 magenta
    hub.ctl("fault dom16:0 delay 1 300ms");
    RawClient writer(gateway.port());
    ASSERT_TRUE(writer.send(adu(7, 1, write_dom16)));
    // The device has the command once the simulator holds the value; its answer is 300 ms away.
    ASSERT_TRUE(eventually([&] { return hub.ctl("get dom16:0").find("4660") == 0; }, 2s));
    const auto signalled = Clock::now();
    EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0) << "not stopped with exit 0 within 2 s";
    EXPECT_LT(Clock::now() - signalled, 2s);
    const auto response = writer.receive(1s);
    ASSERT_TRUE(response) << "the write in flight got no response";
    EXPECT_EQ(response->transaction, 7);
    EXPECT_EQ(response->pdu, write_dom16) << "the write in flight did not get its normal response";
}

TEST(Shutdown, SigtermFinishesTheWriteInFlightAndKeepsTheOutputs) {
    SimProcess hub("--hub", "dom16:0,rgbdm:0", {"--no-line-timing"});
    GatewayProcess gateway(outputs_yaml(hub.link(), "keep"));
    stop_with_a_write_in_flight(hub, gateway);
    EXPECT_EQ(hub.ctl("get dom16:0"), "4660\n");
    EXPECT_EQ(hub.ctl("get rgbdm:0"), "5\n");
}

TEST(Shutdown, OnShutdownInitialSetsEveryOutputToItsInitialValue) {
    SimProcess hub("--hub", "dom16:0,rgbdm:0", {"--no-line-timing"});
    GatewayProcess gateway(outputs_yaml(hub.link(), "initial"));
    stop_with_a_write_in_flight(hub, gateway);
    EXPECT_EQ(hub.ctl("get dom16:0"), "255\n");
    EXPECT_EQ(hub.ctl("get rgbdm:0"), "1\n");
    EXPECT_NE(gateway.log().find("2 output module(s) set to their initial values"),
              std::string::npos);
}

std::string three_links_yaml(const std::string& hub0, const std::string& hub1,
                             std::string_view hub1_timeout, std::string_view third_name,
                             int third_unit, const std::string& third) {
    return fmt::format(R"(modbus: {{ listen: "127.0.0.1:0" }}
links:
  - {{ name: hub0, protocol: ioport, device: {}, unit_id: 1, timeout: 30ms, modules: [{{ type: dim16, number: 0 }}] }}
  - {{ name: hub1, protocol: ioport, device: {}, unit_id: 2, timeout: {}, modules: [{{ type: dim16, number: 0 }}] }}
  - {{ name: {}, protocol: ioport, device: {}, unit_id: {}, timeout: 30ms, modules: [{{ type: dim16, number: 0 }}] }}
)",
                       hub0, hub1, hub1_timeout, third_name, third, third_unit);
}

std::uint32_t counter(ModbusClient& client, int address) {
    const auto words = client.read_input_registers(address, 2);
    return words ? (std::uint32_t{(*words)[0]} << 16) | (*words)[1] : 0;
}

TEST(Reload, AValidConfigKeepsWhatItDoesNotChange) {
    SimProcess a("--hub", "dim16:0", {"--no-line-timing"});
    SimProcess b("--hub", "dim16:0", {"--no-line-timing"});
    SimProcess c("--hub", "dim16:0", {"--no-line-timing"});
    TempDir dir;
    NotifySocket notify(dir / "notify");
    GatewayProcess gateway(three_links_yaml(a.link(), b.link(), "30ms", "old", 3, c.link()), {},
                           {"NOTIFY_SOCKET=" + notify.path()});
    ASSERT_FALSE(notify.wait_for("READY=1", 5s).empty());
    ModbusClient client(gateway.port());
    ASSERT_TRUE(eventually([&] { return counter(client, 1002) > 5; }));  // hub0's cycles
    const auto cycles = counter(client, 1002);

    // hub1 changes, "old" goes and "new" comes on the same port: it must be let go first.
    gateway.rewrite_config(three_links_yaml(a.link(), b.link(), "40ms", "new", 4, c.link()));
    gateway.signal(SIGHUP);
    ASSERT_TRUE(gateway.wait_for_log("SIGHUP: reloaded"));
    EXPECT_NE(gateway.log().find("links kept: hub0; restarted: hub1; added: new; removed: old; "
                                 "Modbus settings unchanged"),
              std::string::npos);
    EXPECT_FALSE(notify.wait_for("RELOADING=1", 2s).empty());
    EXPECT_FALSE(notify.wait_for("READY=1", 2s).empty());

    // The same connection goes on; hub0 was not restarted: its port was opened once and its
    // cycle count goes on from where it was.
    EXPECT_EQ(counter(client, 1008), 1U);
    EXPECT_GE(counter(client, 1002), cycles);
    client.set_unit(3);
    EXPECT_EQ(client.read_input_registers(1000, 1).error(), 0x0A);
    client.set_unit(4);
    EXPECT_TRUE(eventually([&] {
        auto state = client.read_input_registers(1000, 1);
        return state && (*state)[0] == 1;
    }));
    client.set_unit(2);
    EXPECT_TRUE(eventually([&] {
        auto state = client.read_input_registers(1000, 1);
        return state && (*state)[0] == 1;
    }));
}

std::string tagged_hub_yaml(const std::string& device, std::string_view acm3p_tags) {
    return fmt::format(R"(modbus: {{ listen: "127.0.0.1:0" }}
links:
  - name: hub0
    protocol: ioport
    device: {}
    timeout: 30ms
    modules:
      - {{ type: dom16, number: 0, initial: 0 }}
      - {{ type: acm3p, number: 0{} }}
)",
                       device, acm3p_tags);
}

std::optional<float> float_at(ModbusClient& client, int address) {
    const auto words = client.read_input_registers(address, 2);
    if (!words) return std::nullopt;
    return std::bit_cast<float>(std::uint32_t{(*words)[0]} << 16 | (*words)[1]);
}

// gateway.md §6.1: names, units and scales apply at once, without restarting the link: its port
// stays open and its outputs keep the state clients wrote.
TEST(Reload, ARenameOrRescaleAppliesAtOnceAndKeepsTheLink) {
    SimProcess hub("--hub", "dom16:0,acm3p:0", {"--no-line-timing"});
    hub.ctl("set acm3p:0 32768 0 0");
    GatewayProcess gateway(tagged_hub_yaml(hub.link(), ""));
    ModbusClient client(gateway.port());
    const float percent = static_cast<float>(32768 / 65535.0 * 100.0);
    ASSERT_TRUE(eventually([&] { return float_at(client, 200) == percent; }));
    ASSERT_TRUE(client.write_register(0, 0x00FF));
    ASSERT_EQ(hub.ctl("get dom16:0"), "255\n");

    gateway.rewrite_config(tagged_hub_yaml(
        hub.link(),
        R"(, name: boiler, channels: { 0: { name: t, unit: "°C", scale: [0, 100, -20, 150] } })"));
    gateway.signal(SIGHUP);
    ASSERT_TRUE(gateway.wait_for_log("SIGHUP: reloaded"));
    EXPECT_NE(gateway.log().find("links kept: hub0; restarted: none"), std::string::npos)
        << gateway.log();
    EXPECT_NE(gateway.log().find("names, units or scales changed: hub0"), std::string::npos)
        << gateway.log();
    // The float is rescaled at once, not at the next change of the reading.
    const float celsius = static_cast<float>(-20.0 + 32768 / 65535.0 * 100.0 * 1.7);
    EXPECT_EQ(float_at(client, 200), celsius);
    EXPECT_EQ(counter(client, 1008), 1U);  // the port was opened once
    EXPECT_EQ(client.read_holding_registers(0, 1).value_or(std::vector<std::uint16_t>{}),
              std::vector<std::uint16_t>{0x00FF});
    EXPECT_EQ(hub.ctl("get dom16:0"), "255\n");

    // And back: unscaled again.
    const auto from = gateway.log().size();
    gateway.rewrite_config(tagged_hub_yaml(hub.link(), ""));
    gateway.signal(SIGHUP);
    ASSERT_TRUE(gateway.wait_for_log("names, units or scales changed: hub0", 5s, from));
    EXPECT_EQ(float_at(client, 200), percent);
}

TEST(Reload, AnInvalidConfigIsRejectedAndTheRunningOneKept) {
    SimProcess hub("--hub", "dim16:0,dom16:0", {"--no-line-timing"});
    GatewayProcess gateway(hub_yaml(hub.link()));
    ModbusClient client(gateway.port());
    ASSERT_TRUE(eventually([&] { return counter(client, 1002) > 2; }));
    gateway.rewrite_config(hub_yaml(hub.link()) + "bogus: 1\n");
    gateway.signal(SIGHUP);
    ASSERT_TRUE(gateway.wait_for_log("the running configuration is kept"));
    EXPECT_NE(gateway.log().find("ioportd.yaml:5: bogus: unknown key"), std::string::npos)
        << gateway.log();
    EXPECT_TRUE(client.write_register(0, 0x00AA));
    EXPECT_EQ(hub.ctl("get dom16:0"), "170\n");
    EXPECT_EQ(counter(client, 1008), 1U);
    EXPECT_TRUE(gateway.running());
}

TEST(Reload, AListenAddressThatCannotBeBoundChangesNothing) {
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    GatewayProcess gateway(R"(modbus: { listen: "127.0.0.1:0", read_only: true }
links: [{ name: hub0, protocol: ioport, device: )" +
                           hub.link() + R"(, modules: [{ type: dim16, number: 0 }] }]
)");
    GatewayProcess squatter(R"(modbus: { listen: "127.0.0.1:0" }
links: [{ name: hub0, protocol: ioport, device: /dev/null/none, modules: [{ type: dim16, number: 0 }] }]
)");
    gateway.rewrite_config(fmt::format(R"(modbus: {{ listen: "127.0.0.1:{}" }}
links: [{{ name: hub0, protocol: ioport, device: {}, modules: [{{ type: dim16, number: 0 }}] }}]
)",
                                       squatter.port(), hub.link()));
    gateway.signal(SIGHUP);
    ASSERT_TRUE(gateway.wait_for_log("the running configuration is kept"));
    EXPECT_NE(gateway.log().find(fmt::format("cannot listen on 127.0.0.1:{}", squatter.port())),
              std::string::npos);
    ModbusClient client(gateway.port());
    EXPECT_EQ(client.write_coil(0, true).error(), 0x01);  // still read-only
}

TEST(Reload, ANewListenAddressMovesTheServerAndAllowClosesRefusedClients) {
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    const auto yaml = [&](std::string_view modbus) {
        return fmt::format(R"(modbus: {}
links: [{{ name: hub0, protocol: ioport, device: {}, modules: [{{ type: dim16, number: 0 }}] }}]
)",
                           modbus, hub.link());
    };
    GatewayProcess gateway(yaml(R"({ listen: "127.0.0.1:0" })"));
    ModbusClient kept(gateway.port());
    ASSERT_TRUE(kept.read_input_registers(1000, 1));
    gateway.rewrite_config(yaml(R"({ listen: "127.0.0.2:0", allow: ["127.0.0.0/8"] })"));
    gateway.signal(SIGHUP);
    ASSERT_TRUE(gateway.wait_for_log("SIGHUP: reloaded"));
    EXPECT_NE(gateway.log().find("Modbus TCP on 127.0.0.2:"), std::string::npos);
    EXPECT_TRUE(kept.read_input_registers(1000, 1)) << "an allowed client was dropped";
    gateway.rewrite_config(yaml(R"({ listen: "127.0.0.2:0", allow: ["10.0.0.0/8"] })"));
    const auto from = gateway.log().size();
    gateway.signal(SIGHUP);
    ASSERT_TRUE(gateway.wait_for_log("SIGHUP: reloaded", 5s, from));
    EXPECT_NE(gateway.log().find("closed: not in the reloaded modbus.allow", from),
              std::string::npos);
    EXPECT_FALSE(kept.read_input_registers(1000, 1));
}

}  // namespace
}  // namespace ioport::test
