#include "protocol/id2.hpp"

#include <fmt/format.h>

namespace ioport::id2 {

std::string_view name(Command command) {
    switch (command) {
        case Command::stop_input:
            return "stop input";
        case Command::count:
            return "counter";
        case Command::reset:
            return "reset";
    }
    return "?";
}

std::size_t reply_length(Command command) {
    switch (command) {
        case Command::stop_input:
            return 1;
        case Command::count:
            return 5;
        case Command::reset:
            return 2;
    }
    return 0;
}

std::string encode_request(Command command) {
    return std::string(1, static_cast<char>(command));
}

Result<std::uint16_t> parse_reply(Command command, std::string_view frame) {
    const auto bad = [&](std::string_view expected) {
        return fail(Errc::malformed, fmt::format("ID-2 {} answered \"{}\", expected {}",
                                                 name(command), printable(frame), expected));
    };
    switch (command) {
        case Command::stop_input:
            if (frame == "0" || frame == "1") return static_cast<std::uint16_t>(frame[0] - '0');
            return bad("0 or 1");
        case Command::count: {
            if (frame.size() != 5) return bad("5 decimal digits");
            unsigned value = 0;
            for (const char c : frame) {
                if (c < '0' || c > '9') return bad("5 decimal digits");
                value = value * 10 + static_cast<unsigned>(c - '0');
            }
            if (value > 65535) return bad("a count up to 65535");
            return static_cast<std::uint16_t>(value);
        }
        case Command::reset:
            if (frame == "OK") return std::uint16_t{0};
            return bad("OK");
    }
    return bad("a known command");
}

std::optional<Command> parse_request(char byte) {
    switch (byte) {
        case 'I':
            return Command::stop_input;
        case 'C':
            return Command::count;
        case 'R':
            return Command::reset;
        default:
            return std::nullopt;
    }
}

std::string encode_stop_input(bool high) {
    return high ? "1\n" : "0\n";
}
std::string encode_count(std::uint16_t count) {
    return fmt::format("{:05}\n", count);
}
std::string encode_reset_ok() {
    return "OK\n";
}

}  // namespace ioport::id2
