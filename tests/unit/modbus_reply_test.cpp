// The libmodbus side of the Modbus server: what the client receives for a request, read back from
// the other end of a socket pair.
#include <gtest/gtest.h>

#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

#include "daemon/modbus_reply.hpp"

namespace ioport::daemon {
namespace {

using Bytes = std::vector<std::uint8_t>;

class ModbusReply : public ::testing::Test {
  protected:
    void SetUp() override {
        ASSERT_EQ(::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sockets_.data()), 0);
        context_ = modbus_new_tcp(nullptr, 0);
        ASSERT_NE(context_, nullptr);
        modbus_set_socket(context_, sockets_[0]);
    }
    void TearDown() override {
        if (context_ != nullptr) modbus_free(context_);
        for (const int fd : sockets_)
            if (fd >= 0) ::close(fd);
    }

    // What the client receives: one response, at most 260 bytes.
    Bytes received() {
        std::array<std::uint8_t, 512> buffer{};
        const auto n = ::recv(sockets_[1], buffer.data(), buffer.size(), MSG_DONTWAIT);
        return n > 0 ? Bytes(buffer.begin(), buffer.begin() + n) : Bytes{};
    }

    modbus_t* context_ = nullptr;
    std::array<int, 2> sockets_{-1, -1};
};

// Transaction 0x1234, unit 1, and the PDU.
Bytes adu(const Bytes& pdu) {
    Bytes bytes(7 + pdu.size());
    const std::array<std::uint8_t, 7> header{
        0x12, 0x34, 0x00, 0x00, 0x00, static_cast<std::uint8_t>(pdu.size() + 1), 0x01};
    std::copy(header.begin(), header.end(), bytes.begin());
    std::copy(pdu.begin(), pdu.end(), bytes.begin() + 7);
    return bytes;
}

TEST_F(ModbusReply, AnExceptionHasTheHighBitSetWhateverTheFunctionCode) {
    for (int code = 0; code <= 0xFF; ++code) {
        const auto function = static_cast<std::uint8_t>(code);
        const PaddedRequest request(adu({function}));
        ASSERT_EQ(reply_exception(context_, request, modbus::Exception::illegal_function), 9);
        const Bytes expected{0x12, 0x34, 0x00, 0x00,
                             0x00, 0x03, 0x01, static_cast<std::uint8_t>(function | 0x80),
                             0x01};
        EXPECT_EQ(received(), expected) << "function code " << code;
    }
}

TEST_F(ModbusReply, ReadsAnswerFromTheImage) {
    UnitImage image;
    image.tables().input_registers[1000] = 0xBEEF;
    image.tables().input_registers[1001] = 0x0102;
    image.tables().discrete_inputs[3] = 1;
    ASSERT_GT(reply(context_, PaddedRequest(adu({0x04, 0x03, 0xE8, 0x00, 0x02})), image.mapping()),
              0);
    EXPECT_EQ(received(), (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x07, 0x01, 0x04, 0x04, 0xBE, 0xEF,
                                 0x01, 0x02}));
    ASSERT_GT(reply(context_, PaddedRequest(adu({0x02, 0x00, 0x00, 0x00, 0x05})), image.mapping()),
              0);
    EXPECT_EQ(received(), (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x04, 0x01, 0x02, 0x01, 0x08}));
}

TEST_F(ModbusReply, TheImageCoversEveryTable) {
    UnitImage image;
    const auto& tables = image.tables();
    EXPECT_EQ(tables.coils.size(), gateway::coil_count);
    EXPECT_EQ(tables.discrete_inputs.size(), gateway::discrete_input_count);
    EXPECT_EQ(tables.holding_registers.size(), gateway::holding_register_count);
    EXPECT_EQ(tables.input_registers.size(), gateway::input_register_count);
    // The last address of each table, through libmodbus.
    tables.holding_registers.back() = 0x0707;
    ASSERT_GT(reply(context_, PaddedRequest(adu({0x03, 0x00, 0x17, 0x00, 0x01})), image.mapping()),
              0);
    EXPECT_EQ(received(),
              (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x07, 0x07}));
}

TEST_F(ModbusReply, AWriteIsBuiltInTheScratchMappingAndEchoed) {
    const auto scratch = scratch_mapping();
    const Bytes request = adu({0x0F, 0x00, 0x7C, 0x00, 0x04, 0x01, 0x0F});  // coils 124-127 on
    ASSERT_GT(reply(context_, PaddedRequest(request), scratch.get()), 0);
    EXPECT_EQ(received(),
              (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x06, 0x01, 0x0F, 0x00, 0x7C, 0x00, 0x04}));
    EXPECT_EQ(scratch->tab_bits[127], 1);
}

}  // namespace
}  // namespace ioport::daemon
