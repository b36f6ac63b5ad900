// Modbus TCP framing and request decoding: pure functions over bytes (no sockets, no libmodbus).
// The server frames requests by their MBAP header and checks every request here before
// libmodbus builds the response, so libmodbus never takes one of its exception paths (some of
// which sleep for the response timeout).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "protocol/error.hpp"

namespace ioport::modbus {

inline constexpr std::size_t mbap_length = 7;        // transaction, protocol, length, unit
inline constexpr std::size_t max_adu_length = 260;   // MBAP + 253-byte PDU
inline constexpr std::uint16_t min_mbap_length = 2;  // the length field: unit id + PDU
inline constexpr std::uint16_t max_mbap_length = 254;
inline constexpr std::uint16_t max_read_bits = 2000;
inline constexpr std::uint16_t max_read_registers = 125;
inline constexpr std::uint16_t max_write_bits = 1968;
inline constexpr std::uint16_t max_write_registers = 123;
inline constexpr std::uint16_t max_read_write_registers = 121;  // FC 23's write part

enum class Function : std::uint8_t {
    read_coils = 0x01,
    read_discrete_inputs = 0x02,
    read_holding_registers = 0x03,
    read_input_registers = 0x04,
    write_single_coil = 0x05,
    write_single_register = 0x06,
    write_multiple_coils = 0x0F,
    write_multiple_registers = 0x10,
    read_write_multiple_registers = 0x17,
};

enum class Exception : std::uint8_t {
    illegal_function = 0x01,
    illegal_data_address = 0x02,
    illegal_data_value = 0x03,
    server_device_failure = 0x04,
    server_device_busy = 0x06,
    gateway_path_unavailable = 0x0A,
    gateway_target_failed = 0x0B,
};

enum class Table : std::uint8_t { coils, discrete_inputs, holding_registers, input_registers };
std::string_view to_string(Table table);  // "coils", "discrete inputs", …

struct Mbap {
    std::uint16_t transaction = 0;
    std::uint16_t protocol = 0;
    std::uint16_t length = 0;  // bytes that follow the length field: unit id + PDU
    std::uint8_t unit = 0;
};
Mbap parse_mbap(std::span<const std::uint8_t, mbap_length> header);
// Protocol id 0 and length 2..254; otherwise malformed, with a message for the log naming the
// field and its value. A malformed header closes the connection; it is never answered.
Result<> check_mbap(const Mbap& header);

// Frames a TCP byte stream into requests by their MBAP header. `buffered` holds the bytes
// received and not yet handled, oldest first. Returns the complete request at its front (MBAP
// header, unit id and PDU: the prefix of `buffered` that the length field announces), nullopt
// when more bytes are needed, or check_mbap's error when the header at the front is malformed.
// A request is at most max_adu_length bytes, so a buffer that long always has room for the rest
// of an unfinished one.
Result<std::optional<std::span<const std::uint8_t>>> next_adu(
    std::span<const std::uint8_t> buffered);

// A decoded request PDU. Only the function code is checked here, so that the gateway can apply
// the exception precedence of gateway.md §4 (read_only before quantity, and so on).
struct Request {
    Function function{};
    Table table{};
    bool write = false;
    std::uint16_t address = 0;   // FC23: of the write
    std::uint16_t quantity = 0;  // 1 for FC05/FC06; FC23: of the write
    // FC05: the 2-byte value; FC06: the 2-byte register; FC15: the packed coils (LSB first);
    // FC16 and FC23: big-endian registers. Empty for reads.
    std::span<const std::uint8_t> values;
    // FC23 only: the holding registers read once the write is done.
    std::uint16_t read_address = 0;
    std::uint16_t read_quantity = 0;
    // The PDU has exactly the length its function requires and FC15/16/23's byte count matches
    // the quantity. When false, the other fields are only as far as the PDU reached.
    bool well_formed = false;
};
// `pdu` is the function code and what follows it (the MBAP header and unit id stripped).
// Fails with illegal_function for a function other than 01–06, 0F, 10, 17 (and for an empty
// PDU). Function 43 (device identification) is decided on its own: device_identification.hpp.
Expected<Request, Exception> parse_request(std::span<const std::uint8_t> pdu);
// Quantities within the Modbus limits (reads 1–125 registers / 1–2000 bits, writes 1–123 /
// 1–1968, FC23 reads 1–125 and writes 1–121), a well-formed PDU, FC05 value 0x0000 or 0xFF00;
// otherwise illegal_data_value.
std::optional<Exception> check_limits(const Request& request);

// Values of a write request, decoded: FC05 → 0/1, FC06 → the register, FC15 → bit i,
// FC16 and FC23 → register i. `index` < request.quantity; the request must be well formed.
std::uint16_t write_value(const Request& request, std::size_t index);
// The values of a well-formed write request as a person reads them, for the audit trail: bits
// as "1 0 1", registers in decimal "10 20 30".
std::string written_values(const Request& request);

}  // namespace ioport::modbus
