// The ID-2 stop/counter interface: one-character requests, LF-terminated replies.
// Pure functions over bytes and values; see ../shared/spec/protocol.md §2.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "protocol/error.hpp"

namespace ioport::id2 {

inline constexpr char lf = '\n';

enum class Command : char { stop_input = 'I', count = 'C', reset = 'R' };

std::string_view name(Command command);     // "stop input", "counter", "reset"
std::size_t reply_length(Command command);  // 1, 5, 2 characters before the LF
std::string encode_request(Command command);

// The stop input (0/1), the counter (0..65535) or 0 for a reset acknowledged with "OK".
Result<std::uint16_t> parse_reply(Command command, std::string_view frame);

// Device side (the simulator).
std::optional<Command> parse_request(char byte);
std::string encode_stop_input(bool high);
std::string encode_count(std::uint16_t count);
std::string encode_reset_ok();

}  // namespace ioport::id2
