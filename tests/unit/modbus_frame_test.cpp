// Modbus TCP framing and request decoding, frame by frame. Each frame is written out byte by
// byte with what the bytes mean, as they appear on the wire (Modbus Application Protocol
// v1.1b3 and Messaging on TCP/IP v1.0b).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

#include "protocol/modbus.hpp"

namespace ioport::modbus {
namespace {

using Bytes = std::vector<std::uint8_t>;

constexpr std::uint8_t high(std::uint16_t value) {
    return static_cast<std::uint8_t>(value >> 8);
}
constexpr std::uint8_t low(std::uint16_t value) {
    return static_cast<std::uint8_t>(value & 0xFF);
}

// The request's values point into the PDU, so the PDU must outlive it.
Request parsed(const Bytes&& pdu) = delete;
Request parsed(const Bytes& pdu) {
    auto request = parse_request(pdu);
    EXPECT_TRUE(request.has_value());
    return request.has_value() ? *request : Request{};
}

std::optional<Exception> limits(const Bytes& pdu) {
    return check_limits(parsed(pdu));
}

// A read of `quantity` items from `address` with function `code`.
Bytes read_pdu(std::uint8_t code, std::uint16_t address, std::uint16_t quantity) {
    return {
        code,                           // function code
        high(address),  low(address),   // starting address
        high(quantity), low(quantity),  // quantity
    };
}

// A well-formed FC15/FC16 whose values are all zero: byte count as the quantity requires.
Bytes write_multiple_pdu(std::uint8_t code, std::uint16_t address, std::uint16_t quantity) {
    const std::size_t byte_count = code == 0x0F ? (quantity + 7U) / 8U : quantity * 2U;
    // clang-format off
    const std::array<std::uint8_t, 6> head{
        code,                                   // function code
        high(address), low(address),            // starting address
        high(quantity), low(quantity),          // quantity of outputs / registers
        static_cast<std::uint8_t>(byte_count),  // byte count
    };
    // clang-format on
    // Made at its full size, the values zero: growing a 6-byte vector makes GCC 12 at -O3 warn
    // of a copy out of bounds that cannot happen (-Werror=array-bounds in the Release build).
    Bytes pdu(head.size() + byte_count, 0x00);
    std::ranges::copy(head, pdu.begin());
    return pdu;
}

// --- MBAP header ------------------------------------------------------------------------------

TEST(ModbusMbap, FieldsAreBigEndian) {
    const std::array<std::uint8_t, mbap_length> header{
        0x12, 0x34,  // transaction id
        0x00, 0x00,  // protocol id: Modbus
        0x00, 0x06,  // length: unit id + 5-byte PDU
        0x11,        // unit id
    };
    const auto mbap = parse_mbap(header);
    EXPECT_EQ(mbap.transaction, 0x1234);
    EXPECT_EQ(mbap.protocol, 0);
    EXPECT_EQ(mbap.length, 6);
    EXPECT_EQ(mbap.unit, 0x11);
    EXPECT_TRUE(check_mbap(mbap));
}

TEST(ModbusMbap, ProtocolIdOtherThanZeroIsMalformed) {
    const std::array<std::uint8_t, mbap_length> header{
        0x00, 0x01,  // transaction id
        0x00, 0x01,  // protocol id: not Modbus
        0x00, 0x06,  // length
        0x01,        // unit id
    };
    const auto checked = check_mbap(parse_mbap(header));
    ASSERT_FALSE(checked);
    EXPECT_EQ(checked.error().code, Errc::malformed);
    EXPECT_NE(checked.error().message.find("protocol id 1"), std::string::npos)
        << checked.error().message;
}

TEST(ModbusMbap, LengthFieldMustBe2To254) {
    const auto with_length = [](std::uint16_t length) {
        const std::array<std::uint8_t, mbap_length> header{
            0x00,         0x07,         // transaction id
            0x00,         0x00,         // protocol id
            high(length), low(length),  // length
            0x01,                       // unit id
        };
        return check_mbap(parse_mbap(header));
    };
    EXPECT_FALSE(with_length(0));
    EXPECT_FALSE(with_length(1));  // a unit id and no function code
    EXPECT_TRUE(with_length(2));
    EXPECT_TRUE(with_length(254));
    EXPECT_FALSE(with_length(255));
    EXPECT_FALSE(with_length(0xFFFF));
    const auto failed = with_length(255);
    ASSERT_FALSE(failed);
    EXPECT_NE(failed.error().message.find("length 255"), std::string::npos)
        << failed.error().message;
}

// --- Framing a TCP stream ----------------------------------------------------------------------

// An ADU: MBAP header with the length the PDU needs, then the PDU.
Bytes adu(std::uint16_t transaction, std::uint8_t unit, const Bytes& pdu) {
    const auto length = static_cast<std::uint16_t>(pdu.size() + 1);  // unit id + PDU
    const std::array<std::uint8_t, mbap_length> header{
        high(transaction),
        low(transaction),  // transaction id
        0x00,
        0x00,  // protocol id
        high(length),
        low(length),  // length
        unit,         // unit id
    };
    // Made at its full size, as in write_multiple_pdu().
    Bytes bytes(header.size() + pdu.size());
    std::ranges::copy(pdu, std::ranges::copy(header, bytes.begin()).out);
    return bytes;
}

Bytes concat(Bytes a, const Bytes& b) {
    a.insert(a.end(), b.begin(), b.end());
    return a;
}

TEST(ModbusStream, ACompleteRequestIsTheFrontOfTheBuffer) {
    const auto first = adu(1, 1, read_pdu(0x03, 0, 1));
    const auto stream = concat(first, adu(2, 1, read_pdu(0x04, 8, 2)));  // pipelined
    const auto next = next_adu(stream);
    ASSERT_TRUE(next);
    ASSERT_TRUE(*next);
    EXPECT_EQ((*next)->data(), stream.data());
    EXPECT_EQ((*next)->size(), first.size());
    const auto second = next_adu(std::span(stream).subspan(first.size()));
    ASSERT_TRUE(second && *second);
    EXPECT_EQ((*second)->size(), stream.size() - first.size());
}

TEST(ModbusStream, AnUnfinishedRequestNeedsMoreBytes) {
    const auto whole = adu(1, 1, read_pdu(0x03, 0, 1));
    for (std::size_t size = 0; size < whole.size(); ++size) {
        const auto next = next_adu(std::span(whole).first(size));
        ASSERT_TRUE(next) << size << " bytes";
        EXPECT_FALSE(*next) << size << " bytes";
    }
}

TEST(ModbusStream, AMalformedHeaderIsAnErrorAsSoonAsItIsComplete) {
    auto bad = adu(1, 1, read_pdu(0x03, 0, 1));
    bad[3] = 0x01;                                                             // protocol id 1
    EXPECT_TRUE(next_adu(std::span(bad).first(mbap_length - 1)).has_value());  // not yet known
    const auto next = next_adu(std::span(bad).first(mbap_length));
    ASSERT_FALSE(next);
    EXPECT_NE(next.error().message.find("protocol id 1"), std::string::npos);
    const Bytes too_long{0x00, 0x01, 0x00, 0x00, 0x00, 0xFF, 0x01};  // length 255
    EXPECT_FALSE(next_adu(too_long));
}

TEST(ModbusStream, TheLongestRequestIsMaxAduLength) {
    const Bytes pdu(max_mbap_length - 1, 0x10);  // the length field's 254 = unit id + 253
    const auto whole = adu(7, 1, pdu);
    ASSERT_EQ(whole.size(), max_adu_length);
    const auto next = next_adu(whole);
    ASSERT_TRUE(next && *next);
    EXPECT_EQ((*next)->size(), max_adu_length);
    EXPECT_FALSE(*next_adu(std::span(whole).first(max_adu_length - 1)));
}

// --- Each function code -------------------------------------------------------------------------

TEST(ModbusRequest, ReadCoils) {
    const Bytes pdu{
        0x01,        // function: read coils
        0x00, 0x13,  // starting address 19
        0x00, 0x25,  // quantity 37
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::read_coils);
    EXPECT_EQ(request.table, Table::coils);
    EXPECT_FALSE(request.write);
    EXPECT_EQ(request.address, 19);
    EXPECT_EQ(request.quantity, 37);
    EXPECT_TRUE(request.values.empty());
    EXPECT_TRUE(request.well_formed);
    EXPECT_EQ(check_limits(request), std::nullopt);
}

TEST(ModbusRequest, ReadDiscreteInputs) {
    const Bytes pdu{
        0x02,        // function: read discrete inputs
        0x00, 0xC4,  // starting address 196
        0x00, 0x16,  // quantity 22
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::read_discrete_inputs);
    EXPECT_EQ(request.table, Table::discrete_inputs);
    EXPECT_FALSE(request.write);
    EXPECT_EQ(request.address, 196);
    EXPECT_EQ(request.quantity, 22);
    EXPECT_TRUE(request.well_formed);
}

TEST(ModbusRequest, ReadHoldingRegisters) {
    const Bytes pdu{
        0x03,        // function: read holding registers
        0x00, 0x6B,  // starting address 107
        0x00, 0x03,  // quantity 3
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::read_holding_registers);
    EXPECT_EQ(request.table, Table::holding_registers);
    EXPECT_FALSE(request.write);
    EXPECT_EQ(request.address, 107);
    EXPECT_EQ(request.quantity, 3);
    EXPECT_TRUE(request.well_formed);
}

TEST(ModbusRequest, ReadInputRegisters) {
    const Bytes pdu{
        0x04,        // function: read input registers
        0x04, 0x4C,  // starting address 1100
        0x00, 0x48,  // quantity 72
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::read_input_registers);
    EXPECT_EQ(request.table, Table::input_registers);
    EXPECT_FALSE(request.write);
    EXPECT_EQ(request.address, 1100);
    EXPECT_EQ(request.quantity, 72);
    EXPECT_TRUE(request.well_formed);
}

TEST(ModbusRequest, WriteSingleCoil) {
    const Bytes pdu{
        0x05,        // function: write single coil
        0x00, 0xAC,  // output address 172
        0xFF, 0x00,  // value: ON
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::write_single_coil);
    EXPECT_EQ(request.table, Table::coils);
    EXPECT_TRUE(request.write);
    EXPECT_EQ(request.address, 172);
    EXPECT_EQ(request.quantity, 1);
    ASSERT_EQ(request.values.size(), 2U);
    EXPECT_EQ(request.values[0], 0xFF);
    EXPECT_EQ(request.values[1], 0x00);
    EXPECT_TRUE(request.well_formed);
    EXPECT_EQ(check_limits(request), std::nullopt);
    EXPECT_EQ(write_value(request, 0), 1);
}

TEST(ModbusRequest, WriteSingleCoilOff) {
    const Bytes pdu{
        0x05,        // function: write single coil
        0x00, 0x00,  // output address 0
        0x00, 0x00,  // value: OFF
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(check_limits(request), std::nullopt);
    EXPECT_EQ(write_value(request, 0), 0);
}

TEST(ModbusRequest, WriteSingleCoilTakesOnlyFF00OrZero) {
    for (const std::uint16_t value :
         std::array<std::uint16_t, 6>{0x0001, 0x00FF, 0x0100, 0xFF01, 0xFFFF, 0x8000}) {
        // clang-format off
        const Bytes pdu{
            0x05,                     // function: write single coil
            0x00, 0x01,               // output address 1
            high(value), low(value),  // value: neither ON nor OFF
        };
        // clang-format on
        EXPECT_EQ(limits(pdu), Exception::illegal_data_value) << value;
    }
}

TEST(ModbusRequest, WriteSingleRegister) {
    const Bytes pdu{
        0x06,        // function: write single register
        0x00, 0x01,  // register address 1
        0xBE, 0xEF,  // value 0xBEEF
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::write_single_register);
    EXPECT_EQ(request.table, Table::holding_registers);
    EXPECT_TRUE(request.write);
    EXPECT_EQ(request.address, 1);
    EXPECT_EQ(request.quantity, 1);
    EXPECT_TRUE(request.well_formed);
    EXPECT_EQ(check_limits(request), std::nullopt);  // any 16-bit value: the map decides
    EXPECT_EQ(write_value(request, 0), 0xBEEF);
}

TEST(ModbusRequest, WriteMultipleCoils) {
    const Bytes pdu{
        0x0F,        // function: write multiple coils
        0x00, 0x13,  // starting address 19
        0x00, 0x0A,  // quantity 10
        0x02,        // byte count
        0xCD,        // coils 19-26: 1 0 1 1 0 0 1 1 (LSB first)
        0x01,        // coils 27-28: 1 0, the rest padding
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::write_multiple_coils);
    EXPECT_EQ(request.table, Table::coils);
    EXPECT_TRUE(request.write);
    EXPECT_EQ(request.address, 19);
    EXPECT_EQ(request.quantity, 10);
    EXPECT_EQ(request.values.size(), 2U);
    EXPECT_TRUE(request.well_formed);
    EXPECT_EQ(check_limits(request), std::nullopt);
    const std::array<std::uint16_t, 10> bits{1, 0, 1, 1, 0, 0, 1, 1, 1, 0};
    for (std::size_t i = 0; i < bits.size(); ++i)
        EXPECT_EQ(write_value(request, i), bits[i]) << i;
}

TEST(ModbusRequest, WriteMultipleRegisters) {
    const Bytes pdu{
        0x10,        // function: write multiple registers
        0x00, 0x01,  // starting address 1
        0x00, 0x02,  // quantity 2
        0x04,        // byte count
        0x00, 0x0A,  // register 1: 10
        0x01, 0x02,  // register 2: 258
    };
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::write_multiple_registers);
    EXPECT_EQ(request.table, Table::holding_registers);
    EXPECT_TRUE(request.write);
    EXPECT_EQ(request.address, 1);
    EXPECT_EQ(request.quantity, 2);
    EXPECT_EQ(request.values.size(), 4U);
    EXPECT_TRUE(request.well_formed);
    EXPECT_EQ(check_limits(request), std::nullopt);
    EXPECT_EQ(write_value(request, 0), 10);
    EXPECT_EQ(write_value(request, 1), 258);
}

// The example of Modbus Application Protocol v1.1b3 §6.17: read 6 registers from register 4,
// write 3 registers from register 15.
TEST(ModbusRequest, ReadWriteMultipleRegistersAsTheSpecificationWritesIt) {
    // clang-format off
    const Bytes pdu{
        0x17,                    // function code
        0x00, 0x03,              // read starting address
        0x00, 0x06,              // quantity to read
        0x00, 0x0E,              // write starting address
        0x00, 0x03,              // quantity to write
        0x06,                    // write byte count
        0x00, 0xFF, 0x00, 0xFF, 0x00, 0xFF,  // write registers values
    };
    // clang-format on
    const auto request = parsed(pdu);
    EXPECT_EQ(request.function, Function::read_write_multiple_registers);
    EXPECT_EQ(request.table, Table::holding_registers);
    EXPECT_TRUE(request.write);
    EXPECT_EQ(request.read_address, 3);
    EXPECT_EQ(request.read_quantity, 6);
    EXPECT_EQ(request.address, 14);
    EXPECT_EQ(request.quantity, 3);
    EXPECT_TRUE(request.well_formed);
    EXPECT_EQ(write_value(request, 2), 0x00FF);
    EXPECT_EQ(check_limits(request), std::nullopt);
}

// §5.2: reads 1-125, writes 1-121, byte count = 2 × write quantity, else 03.
TEST(ModbusRequest, ReadWriteMultipleRegistersLimits) {
    const auto read_write = [](std::uint16_t read_quantity, std::uint16_t write_quantity,
                               std::uint8_t byte_count, std::size_t values) {
        // Sized at once: GCC 12 at -O3 takes growing a vector past its initializer for an
        // out-of-bounds copy.
        Bytes pdu(10 + values, 0x00);
        pdu[0] = 0x17;
        pdu[3] = high(read_quantity);
        pdu[4] = low(read_quantity);
        pdu[7] = high(write_quantity);
        pdu[8] = low(write_quantity);
        pdu[9] = byte_count;
        return pdu;
    };
    EXPECT_EQ(limits(read_write(125, 121, 242, 242)), std::nullopt);
    EXPECT_EQ(limits(read_write(1, 1, 2, 2)), std::nullopt);
    EXPECT_EQ(limits(read_write(0, 1, 2, 2)), Exception::illegal_data_value);
    EXPECT_EQ(limits(read_write(126, 1, 2, 2)), Exception::illegal_data_value);
    EXPECT_EQ(limits(read_write(1, 0, 0, 0)), Exception::illegal_data_value);
    EXPECT_EQ(limits(read_write(1, 122, 244, 244)), Exception::illegal_data_value);
    EXPECT_EQ(limits(read_write(1, 2, 2, 2)), Exception::illegal_data_value);  // byte count
    EXPECT_EQ(limits(read_write(1, 1, 2, 3)), Exception::illegal_data_value);  // trailing byte
    EXPECT_EQ(limits(read_write(1, 1, 2, 1)), Exception::illegal_data_value);  // cut short
    Bytes cut{0x17, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00};  // ends inside the header
    EXPECT_EQ(limits(cut), Exception::illegal_data_value);
}

TEST(ModbusRequest, OtherFunctionsAreIllegal) {
    const std::array<Bytes, 6> pdus{{
        {},                                          // no function code at all
        {0x07},                                      // read exception status (serial line only)
        {0x08, 0x00, 0x00, 0x12, 0x34},              // diagnostics, return query data
        {0x16, 0x00, 0x04, 0x00, 0xF2, 0x00, 0x25},  // mask write register
        // read device identification: answered on its own (device_identification.hpp), never
        // planned as a read or a write
        {0x2B, 0x0E, 0x01, 0x00},
        {0x81, 0x00, 0x00, 0x00, 0x01},  // an exception response sent as a request
    }};
    for (const auto& pdu : pdus) {
        const auto request = parse_request(pdu);
        ASSERT_FALSE(request.has_value()) << (pdu.empty() ? -1 : pdu[0]);
        EXPECT_EQ(request.error(), Exception::illegal_function);
    }
}

// --- Mis-sized PDUs
// -------------------------------------------------------------------------------

TEST(ModbusRequest, ReadPduMustBeExactlyFiveBytes) {
    const Bytes short_read_pdu{
        0x03,        // function: read holding registers
        0x00, 0x01,  // starting address 1
        0x00,        // quantity, cut short
    };
    const auto short_read = parsed(short_read_pdu);
    EXPECT_FALSE(short_read.well_formed);
    EXPECT_EQ(short_read.address, 1);  // as far as the PDU reached
    EXPECT_EQ(check_limits(short_read), Exception::illegal_data_value);

    const Bytes long_read_pdu{
        0x04,        // function: read input registers
        0x00, 0x00,  // starting address 0
        0x00, 0x01,  // quantity 1
        0x00,        // one byte too many
    };
    const auto long_read = parsed(long_read_pdu);
    EXPECT_FALSE(long_read.well_formed);
    EXPECT_EQ(long_read.quantity, 1);
    EXPECT_EQ(check_limits(long_read), Exception::illegal_data_value);

    const Bytes bare_pdu{
        0x01,  // function: read coils, and nothing else
    };
    const auto bare = parsed(bare_pdu);
    EXPECT_FALSE(bare.well_formed);
    EXPECT_EQ(check_limits(bare), Exception::illegal_data_value);
}

TEST(ModbusRequest, SingleWritePduMustBeExactlyFiveBytes) {
    const Bytes short_write_pdu{
        0x06,        // function: write single register
        0x00, 0x08,  // register address 8
        0x00,        // value, cut short
    };
    const auto short_write = parsed(short_write_pdu);
    EXPECT_FALSE(short_write.well_formed);
    EXPECT_TRUE(short_write.values.empty());
    EXPECT_EQ(check_limits(short_write), Exception::illegal_data_value);

    const Bytes long_write_pdu{
        0x05,        // function: write single coil
        0x00, 0x00,  // output address 0
        0xFF, 0x00,  // value: ON
        0xFF,        // one byte too many
    };
    const auto long_write = parsed(long_write_pdu);
    EXPECT_FALSE(long_write.well_formed);
    EXPECT_EQ(check_limits(long_write), Exception::illegal_data_value);
}

TEST(ModbusRequest, MultipleWriteWithoutByteCount) {
    const Bytes pdu{
        0x10,        // function: write multiple registers
        0x00, 0x00,  // starting address 0
        0x00, 0x01,  // quantity 1, and no byte count
    };
    const auto request = parsed(pdu);
    EXPECT_FALSE(request.well_formed);
    EXPECT_EQ(request.quantity, 1);
    EXPECT_EQ(check_limits(request), Exception::illegal_data_value);
}

TEST(ModbusRequest, ByteCountMustMatchTheQuantity) {
    const Bytes coils_short_count_pdu{
        0x0F,        // function: write multiple coils
        0x00, 0x00,  // starting address 0
        0x00, 0x0A,  // quantity 10: needs 2 bytes
        0x01,        // byte count 1
        0xFF,        // coils 0-7
    };
    const auto coils_short_count = parsed(coils_short_count_pdu);
    EXPECT_FALSE(coils_short_count.well_formed);
    EXPECT_EQ(check_limits(coils_short_count), Exception::illegal_data_value);

    const Bytes coils_long_count_pdu{
        0x0F,        // function: write multiple coils
        0x00, 0x00,  // starting address 0
        0x00, 0x08,  // quantity 8: needs 1 byte
        0x02,        // byte count 2
        0xFF, 0x00,  // coils 0-7 and a byte too many
    };
    const auto coils_long_count = parsed(coils_long_count_pdu);
    EXPECT_FALSE(coils_long_count.well_formed);

    const Bytes registers_odd_count_pdu{
        0x10,        // function: write multiple registers
        0x00, 0x00,  // starting address 0
        0x00, 0x02,  // quantity 2: needs 4 bytes
        0x03,        // byte count 3
        0x00, 0x01,  // register 0
        0x00,        // half a register
    };
    const auto registers_odd_count = parsed(registers_odd_count_pdu);
    EXPECT_FALSE(registers_odd_count.well_formed);
    EXPECT_EQ(check_limits(registers_odd_count), Exception::illegal_data_value);
}

TEST(ModbusRequest, PduMustEndWithTheBytesTheByteCountAnnounces) {
    const Bytes truncated_pdu{
        0x10,        // function: write multiple registers
        0x00, 0x00,  // starting address 0
        0x00, 0x02,  // quantity 2
        0x04,        // byte count 4
        0x00, 0x01,  // register 0, and register 1 missing
    };
    const auto truncated = parsed(truncated_pdu);
    EXPECT_FALSE(truncated.well_formed);
    EXPECT_EQ(truncated.values.size(), 2U);  // what is there
    EXPECT_EQ(check_limits(truncated), Exception::illegal_data_value);

    const Bytes trailing_pdu{
        0x0F,        // function: write multiple coils
        0x00, 0x00,  // starting address 0
        0x00, 0x01,  // quantity 1
        0x01,        // byte count 1
        0x01,        // coil 0
        0x00,        // a byte after the values
    };
    const auto trailing = parsed(trailing_pdu);
    EXPECT_FALSE(trailing.well_formed);
    EXPECT_EQ(check_limits(trailing), Exception::illegal_data_value);
}

// --- Quantity limits, at the exact boundaries -------------------------------------------------

TEST(ModbusLimits, ReadBits1To2000) {
    for (const std::uint8_t code : {std::uint8_t{0x01}, std::uint8_t{0x02}}) {
        EXPECT_EQ(limits(read_pdu(code, 0, 0)), Exception::illegal_data_value) << int{code};
        EXPECT_EQ(limits(read_pdu(code, 0, 1)), std::nullopt) << int{code};
        EXPECT_EQ(limits(read_pdu(code, 0, 2000)), std::nullopt) << int{code};
        EXPECT_EQ(limits(read_pdu(code, 0, 2001)), Exception::illegal_data_value) << int{code};
    }
}

TEST(ModbusLimits, ReadRegisters1To125) {
    for (const std::uint8_t code : {std::uint8_t{0x03}, std::uint8_t{0x04}}) {
        EXPECT_EQ(limits(read_pdu(code, 0, 0)), Exception::illegal_data_value) << int{code};
        EXPECT_EQ(limits(read_pdu(code, 0, 1)), std::nullopt) << int{code};
        EXPECT_EQ(limits(read_pdu(code, 0, 125)), std::nullopt) << int{code};
        EXPECT_EQ(limits(read_pdu(code, 0, 126)), Exception::illegal_data_value) << int{code};
    }
}

TEST(ModbusLimits, WriteCoils1To1968) {
    EXPECT_EQ(limits(write_multiple_pdu(0x0F, 0, 0)), Exception::illegal_data_value);
    EXPECT_EQ(limits(write_multiple_pdu(0x0F, 0, 1)), std::nullopt);
    EXPECT_EQ(limits(write_multiple_pdu(0x0F, 0, 1968)), std::nullopt);
    EXPECT_EQ(limits(write_multiple_pdu(0x0F, 0, 1969)), Exception::illegal_data_value);
}

TEST(ModbusLimits, WriteRegisters1To123) {
    EXPECT_EQ(limits(write_multiple_pdu(0x10, 0, 0)), Exception::illegal_data_value);
    EXPECT_EQ(limits(write_multiple_pdu(0x10, 0, 1)), std::nullopt);
    EXPECT_EQ(limits(write_multiple_pdu(0x10, 0, 123)), std::nullopt);
    EXPECT_EQ(limits(write_multiple_pdu(0x10, 0, 124)), Exception::illegal_data_value);
}

TEST(ModbusLimits, ZeroQuantityWithNoValuesIsWellFormedButOutOfRange) {
    const Bytes pdu{
        0x0F,        // function: write multiple coils
        0x00, 0x00,  // starting address 0
        0x00, 0x00,  // quantity 0
        0x00,        // byte count 0
    };
    const auto request = parsed(pdu);
    EXPECT_TRUE(request.well_formed);
    EXPECT_EQ(check_limits(request), Exception::illegal_data_value);
}

TEST(ModbusLimits, TheLargestWritesFitOneAdu) {
    // Function code, address, quantity, byte count and the values: at most 253 bytes.
    EXPECT_LE(write_multiple_pdu(0x0F, 0, max_write_bits).size(), max_adu_length - mbap_length);
    EXPECT_LE(write_multiple_pdu(0x10, 0, max_write_registers).size(),
              max_adu_length - mbap_length);
}

TEST(ModbusNames, Tables) {
    EXPECT_EQ(to_string(Table::coils), "coils");
    EXPECT_EQ(to_string(Table::discrete_inputs), "discrete inputs");
    EXPECT_EQ(to_string(Table::holding_registers), "holding registers");
    EXPECT_EQ(to_string(Table::input_registers), "input registers");
}

}  // namespace
}  // namespace ioport::modbus
