// The libmodbus side of the Modbus server: the bytes the client receives for a request.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "daemon/modbus_reply.hpp"

namespace ioport::daemon {
namespace {

class ModbusReply : public ::testing::Test {
  protected:
    void SetUp() override {
        auto created = ReplyBuilder::create();
        ASSERT_TRUE(created) << created.error().message;
        replies_ = std::move(*created);
    }

    std::unique_ptr<ReplyBuilder> replies_;
};

// The response, or nothing after a failure to build it.
Bytes built(const Result<Bytes>& response) {
    if (response) return *response;
    ADD_FAILURE() << response.error().message;
    return {};
}

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
        const auto response = replies_->exception(request, modbus::Exception::illegal_function);
        ASSERT_TRUE(response);
        const Bytes expected{0x12, 0x34, 0x00, 0x00,
                             0x00, 0x03, 0x01, static_cast<std::uint8_t>(function | 0x80),
                             0x01};
        EXPECT_EQ(*response, expected) << "function code " << code;
    }
}

TEST_F(ModbusReply, ReadsAnswerFromTheImage) {
    UnitImage image;
    image.tables().input_registers[1000] = 0xBEEF;
    image.tables().input_registers[1001] = 0x0102;
    image.tables().discrete_inputs[3] = 1;
    EXPECT_EQ(
        built(replies_->reply(PaddedRequest(adu({0x04, 0x03, 0xE8, 0x00, 0x02})), image.mapping())),
        (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x07, 0x01, 0x04, 0x04, 0xBE, 0xEF, 0x01, 0x02}));
    EXPECT_EQ(
        built(replies_->reply(PaddedRequest(adu({0x02, 0x00, 0x00, 0x00, 0x05})), image.mapping())),
        (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x04, 0x01, 0x02, 0x01, 0x08}));
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
    EXPECT_EQ(
        built(replies_->reply(PaddedRequest(adu({0x03, 0x00, 0x17, 0x00, 0x01})), image.mapping())),
        (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x07, 0x07}));
}

TEST_F(ModbusReply, AWriteIsBuiltInTheScratchMappingAndEchoed) {
    const auto scratch = scratch_mapping();
    const Bytes request = adu({0x0F, 0x00, 0x7C, 0x00, 0x04, 0x01, 0x0F});  // coils 124-127 on
    EXPECT_EQ(built(replies_->reply(PaddedRequest(request), scratch.get())),
              (Bytes{0x12, 0x34, 0x00, 0x00, 0x00, 0x06, 0x01, 0x0F, 0x00, 0x7C, 0x00, 0x04}));
    EXPECT_EQ(scratch->tab_bits[127], 1);
}

}  // namespace
}  // namespace ioport::daemon
