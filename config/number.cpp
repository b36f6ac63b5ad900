#include "config/number.hpp"

#include <array>
#include <charconv>
#include <utility>

namespace ioport {

std::optional<unsigned long> parse_unsigned(std::string_view text, unsigned long max) {
    int base = 10;
    if (text.starts_with("0x") || text.starts_with("0X")) {
        base = 16;
        text.remove_prefix(2);
    } else if (text.starts_with("0b") || text.starts_with("0B")) {
        base = 2;
        text.remove_prefix(2);
    }
    unsigned long value = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value, base);
    if (text.empty() || ec != std::errc{} || end != text.data() + text.size() || value > max)
        return std::nullopt;
    return value;
}

std::optional<unsigned long> parse_bytes(std::string_view text, unsigned long max) {
    static constexpr std::array<std::pair<std::string_view, unsigned>, 3> units{
        {{"KiB", 10}, {"MiB", 20}, {"GiB", 30}}};
    unsigned shift = 0;
    for (const auto& [unit, bits] : units)
        if (text.ends_with(unit)) {
            text.remove_suffix(unit.size());
            shift = bits;
            break;
        }
    unsigned long value = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
    if (text.empty() || ec != std::errc{} || end != text.data() + text.size() ||
        value > (max >> shift))
        return std::nullopt;
    return value << shift;
}

}  // namespace ioport
