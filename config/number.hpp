// Whole numbers as people write them in commands and configuration: 37841, 0x93D1, 0b1001.
#pragma once

#include <optional>
#include <string_view>

namespace ioport {

// Decimal, 0x hexadecimal or 0b binary, nothing else around it, and at most `max`.
std::optional<unsigned long> parse_unsigned(std::string_view text, unsigned long max);

// A number of bytes: a decimal whole number, alone or followed by KiB, MiB or GiB (powers of
// 1024), e.g. 65536 or 64MiB; nullopt for anything else or more than `max` bytes.
std::optional<unsigned long> parse_bytes(std::string_view text, unsigned long max);

}  // namespace ioport
