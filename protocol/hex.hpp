// Fixed-width hexadecimal, the ioport wire's only number format.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace ioport {

// One hex digit, either case.
constexpr std::optional<unsigned> hex_digit(char c) {
    if (c >= '0' && c <= '9') return static_cast<unsigned>(c - '0');
    if (c >= 'A' && c <= 'F') return static_cast<unsigned>(c - 'A' + 10);
    if (c >= 'a' && c <= 'f') return static_cast<unsigned>(c - 'a' + 10);
    return std::nullopt;
}

// Exactly four hex digits, either case; nothing else.
constexpr std::optional<std::uint16_t> parse_hex4(std::string_view digits) {
    if (digits.size() != 4) return std::nullopt;
    unsigned value = 0;
    for (const char c : digits) {
        const auto nibble = hex_digit(c);
        if (!nibble) return std::nullopt;
        value = value << 4 | *nibble;
    }
    return static_cast<std::uint16_t>(value);
}

// Upper case, as the vendor's examples send.
inline void append_hex4(std::string& out, std::uint16_t value) {
    static constexpr char digits[] = "0123456789ABCDEF";
    for (int shift = 12; shift >= 0; shift -= 4)
        out += digits[(value >> shift) & 0xF];
}

}  // namespace ioport
