#include "protocol/modbus.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <utility>

namespace ioport::modbus {
namespace {

// Bytes of a read or single-write PDU: function code, two 16-bit fields.
constexpr std::size_t fixed_pdu_length = 5;
// Bytes of a multiple-write PDU before the values: the fixed part and the byte count.
constexpr std::size_t multiple_header_length = 6;
// FC23 before the values: function, read address and quantity, write address and quantity,
// byte count.
constexpr std::size_t read_write_header_length = 10;

std::uint16_t big_endian16(std::span<const std::uint8_t> bytes, std::size_t at) {
    return static_cast<std::uint16_t>(bytes[at] << 8 | bytes[at + 1]);
}

// The field at `at`, or 0 when the PDU ends before it (a mis-sized PDU still reports what it has).
std::uint16_t field(std::span<const std::uint8_t> pdu, std::size_t at) {
    return pdu.size() >= at + 2 ? big_endian16(pdu, at) : std::uint16_t{0};
}

struct Shape {
    Table table;
    bool write;
};

std::optional<Shape> shape(std::uint8_t code) {
    switch (static_cast<Function>(code)) {
        case Function::read_coils:
            return Shape{Table::coils, false};
        case Function::read_discrete_inputs:
            return Shape{Table::discrete_inputs, false};
        case Function::read_holding_registers:
            return Shape{Table::holding_registers, false};
        case Function::read_input_registers:
            return Shape{Table::input_registers, false};
        case Function::write_single_coil:
        case Function::write_multiple_coils:
            return Shape{Table::coils, true};
        case Function::write_single_register:
        case Function::write_multiple_registers:
        case Function::read_write_multiple_registers:
            return Shape{Table::holding_registers, true};
    }
    return std::nullopt;
}

bool is_single_write(Function function) {
    return function == Function::write_single_coil || function == Function::write_single_register;
}

std::size_t expected_byte_count(const Request& request) {
    return request.table == Table::coils ? (std::size_t{request.quantity} + 7) / 8
                                         : std::size_t{request.quantity} * 2;
}

void decode_fixed(Request& request, std::span<const std::uint8_t> pdu) {
    request.address = field(pdu, 1);
    request.well_formed = pdu.size() == fixed_pdu_length;
    if (is_single_write(request.function)) {
        request.quantity = 1;
        if (pdu.size() >= fixed_pdu_length) request.values = pdu.subspan(3, 2);
    } else {
        request.quantity = field(pdu, 3);
    }
}

// The values after the byte count that ends a header of `header` bytes: well formed when they
// are as many as it says and it is what the quantity needs.
void decode_values(Request& request, std::span<const std::uint8_t> pdu, std::size_t header) {
    if (pdu.size() < header) return;
    const std::size_t byte_count = pdu[header - 1];
    const auto present = pdu.subspan(header);
    request.values = present.first(std::min(byte_count, present.size()));
    request.well_formed =
        present.size() == byte_count && byte_count == expected_byte_count(request);
}

void decode_multiple(Request& request, std::span<const std::uint8_t> pdu) {
    request.address = field(pdu, 1);
    request.quantity = field(pdu, 3);
    decode_values(request, pdu, multiple_header_length);
}

void decode_read_write(Request& request, std::span<const std::uint8_t> pdu) {
    request.read_address = field(pdu, 1);
    request.read_quantity = field(pdu, 3);
    request.address = field(pdu, 5);
    request.quantity = field(pdu, 7);
    decode_values(request, pdu, read_write_header_length);
}

std::uint16_t limit(Function function) {
    switch (function) {
        case Function::read_coils:
        case Function::read_discrete_inputs:
            return max_read_bits;
        case Function::read_holding_registers:
        case Function::read_input_registers:
            return max_read_registers;
        case Function::write_multiple_coils:
            return max_write_bits;
        case Function::write_multiple_registers:
            return max_write_registers;
        case Function::read_write_multiple_registers:
            return max_read_write_registers;
        case Function::write_single_coil:
        case Function::write_single_register:
            return 1;
    }
    return 0;
}

}  // namespace

std::string_view to_string(Table table) {
    switch (table) {
        case Table::coils:
            return "coils";
        case Table::discrete_inputs:
            return "discrete inputs";
        case Table::holding_registers:
            return "holding registers";
        case Table::input_registers:
            return "input registers";
    }
    return "unknown table";
}

Mbap parse_mbap(std::span<const std::uint8_t, mbap_length> header) {
    return {big_endian16(header, 0), big_endian16(header, 2), big_endian16(header, 4), header[6]};
}

Result<> check_mbap(const Mbap& header) {
    if (header.protocol != 0)
        return fail(Errc::malformed, fmt::format("MBAP protocol id {} (transaction {}), expected 0",
                                                 header.protocol, header.transaction));
    if (header.length < min_mbap_length || header.length > max_mbap_length)
        return fail(Errc::malformed,
                    fmt::format("MBAP length {} (transaction {}) is outside {}-{}", header.length,
                                header.transaction, min_mbap_length, max_mbap_length));
    return {};
}

Result<std::optional<std::span<const std::uint8_t>>> next_adu(
    std::span<const std::uint8_t> buffered) {
    if (buffered.size() < mbap_length) return std::nullopt;
    const auto header = parse_mbap(buffered.first<mbap_length>());
    if (auto valid = check_mbap(header); !valid) return Unexpected(std::move(valid).error());
    // The length field counts the unit id, the last byte of the MBAP header.
    const std::size_t total = mbap_length - 1 + header.length;
    if (buffered.size() < total) return std::nullopt;
    return buffered.first(total);
}

Expected<Request, Exception> parse_request(std::span<const std::uint8_t> pdu) {
    if (pdu.empty()) return Unexpected(Exception::illegal_function);
    const auto found = shape(pdu[0]);
    if (!found) return Unexpected(Exception::illegal_function);
    Request request;
    request.function = static_cast<Function>(pdu[0]);
    request.table = found->table;
    request.write = found->write;
    if (request.function == Function::write_multiple_coils ||
        request.function == Function::write_multiple_registers)
        decode_multiple(request, pdu);
    else if (request.function == Function::read_write_multiple_registers)
        decode_read_write(request, pdu);
    else
        decode_fixed(request, pdu);
    return request;
}

std::optional<Exception> check_limits(const Request& request) {
    if (!request.well_formed) return Exception::illegal_data_value;
    if (request.quantity < 1 || request.quantity > limit(request.function))
        return Exception::illegal_data_value;
    if (request.function == Function::read_write_multiple_registers &&
        (request.read_quantity < 1 || request.read_quantity > max_read_registers))
        return Exception::illegal_data_value;
    if (request.function == Function::write_single_coil) {
        const auto value = big_endian16(request.values, 0);
        if (value != 0x0000 && value != 0xFF00) return Exception::illegal_data_value;
    }
    return std::nullopt;
}

std::uint16_t write_value(const Request& request, std::size_t index) {
    switch (request.function) {
        case Function::write_single_coil:
            return request.values[0] == 0xFF ? 1 : 0;
        case Function::write_multiple_coils:
            return static_cast<std::uint16_t>(request.values[index / 8] >> (index % 8) & 1);
        case Function::write_multiple_registers:
        case Function::read_write_multiple_registers:
            return big_endian16(request.values, index * 2);
        case Function::write_single_register:
            return big_endian16(request.values, 0);
        case Function::read_coils:
        case Function::read_discrete_inputs:
        case Function::read_holding_registers:
        case Function::read_input_registers:
            break;  // a read carries no values
    }
    return 0;
}

}  // namespace ioport::modbus

namespace ioport::modbus {

std::string written_values(const Request& request) {
    std::string text;
    for (std::size_t i = 0; i < request.quantity; ++i) {
        if (i > 0) text += ' ';
        text += std::to_string(write_value(request, i));
    }
    return text;
}

}  // namespace ioport::modbus
