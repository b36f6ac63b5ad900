// Whole numbers as people write them in commands and configuration: 37841, 0x93D1, 0b1001.
#pragma once

#include <optional>
#include <string_view>

namespace ioport {

// Decimal, 0x hexadecimal or 0b binary, nothing else around it, and at most `max`.
std::optional<unsigned long> parse_unsigned(std::string_view text, unsigned long max);

}  // namespace ioport
