// The libmodbus side of the Modbus server: the bytes the client receives for a request.
#include <gtest/gtest.h>

#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <random>
#include <vector>

#include "daemon/modbus/modbus_reply.hpp"

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

// libmodbus's own response, from the other end of its socket.
class Libmodbus {
  public:
    Libmodbus() {
        if (::socketpair(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0, ends_.data()) != 0) return;
        context_ = modbus_new_tcp(nullptr, 0);
        if (context_ != nullptr) modbus_set_socket(context_, ends_[0]);
    }
    ~Libmodbus() {
        if (context_ != nullptr) modbus_free(context_);
        for (const int fd : ends_)
            if (fd >= 0) ::close(fd);
    }
    Libmodbus(const Libmodbus&) = delete;
    Libmodbus& operator=(const Libmodbus&) = delete;

    bool ready() const { return context_ != nullptr; }
    Bytes reply(Bytes request, modbus_mapping_t* mapping) {
        request.resize(request.size() + 8);  // zero padding, as PaddedRequest gives it
        const int sent =
            modbus_reply(context_, request.data(), static_cast<int>(request.size() - 8), mapping);
        Bytes response(512);
        const auto n = ::recv(ends_[1], response.data(), response.size(), MSG_DONTWAIT);
        response.resize(sent > 0 && n > 0 ? static_cast<std::size_t>(n) : 0);
        return response;
    }

  private:
    std::array<int, 2> ends_{-1, -1};
    modbus_t* context_ = nullptr;
};

// ioportd builds read responses itself (no system call); they must be libmodbus's to the byte,
// at every edge of every table: the first and last addresses, 1 to 2000 bits, 1 to 125
// registers, bit counts that end mid-byte, and the requests libmodbus refuses.
TEST_F(ModbusReply, ReadsAreLibmodbusResponsesToTheByte) {
    Libmodbus libmodbus;
    ASSERT_TRUE(libmodbus.ready());
    UnitImage image;
    std::mt19937 random(7);
    const auto& t = image.tables();
    for (auto& bit : t.coils)
        bit = static_cast<std::uint8_t>(random() & 1U);
    for (auto& bit : t.discrete_inputs)
        bit = static_cast<std::uint8_t>(random() & 1U);
    for (auto& word : t.holding_registers)
        word = static_cast<std::uint16_t>(random());
    for (auto& word : t.input_registers)
        word = static_cast<std::uint16_t>(random());
    const std::array<std::size_t, 4> sizes{t.coils.size(), t.discrete_inputs.size(),
                                           t.holding_registers.size(), t.input_registers.size()};
    int compared = 0;
    for (std::uint8_t function = 1; function <= 4; ++function) {
        const std::size_t size = sizes[function - 1U];
        const std::size_t most = function <= 2 ? 2000 : 125;
        for (const std::size_t quantity : {std::size_t{1}, std::size_t{7}, std::size_t{8},
                                           std::size_t{9}, std::size_t{17}, most}) {
            for (const std::size_t address : {std::size_t{0}, std::size_t{1}, size / 2,
                                              size - std::min(size, quantity), size - 1}) {
                const Bytes request = adu({function, static_cast<std::uint8_t>(address >> 8U),
                                           static_cast<std::uint8_t>(address),
                                           static_cast<std::uint8_t>(quantity >> 8U),
                                           static_cast<std::uint8_t>(quantity)});
                const auto ours = replies_->reply(PaddedRequest(request), image.mapping());
                ASSERT_TRUE(ours) << ours.error().message;
                EXPECT_EQ(*ours, libmodbus.reply(request, image.mapping()))
                    << "function " << int{function} << " address " << address << " quantity "
                    << quantity;
                ++compared;
            }
        }
    }
    EXPECT_EQ(compared, 4 * 6 * 5);
}

}  // namespace
}  // namespace ioport::daemon
