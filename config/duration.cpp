#include "config/duration.hpp"

#include <array>
#include <charconv>
#include <utility>

#include <fmt/format.h>

namespace ioport {
namespace {

constexpr std::array<std::pair<std::string_view, long long>, 4> units{
    {{"us", 1}, {"ms", 1000}, {"s", 1000000}, {"m", 60000000}}};

}  // namespace

Result<std::chrono::microseconds> parse_duration(std::string_view text) {
    const auto bad = [&] {
        return fail(Errc::invalid_argument,
                    fmt::format("'{}' is not a duration: write a whole number and a unit, e.g. "
                                "500us, 100ms, 2s, 5m",
                                text));
    };
    long long count = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), count);
    if (ec != std::errc{} || count < 0) return bad();
    const std::string_view unit(end, static_cast<std::size_t>(text.data() + text.size() - end));
    if (unit.empty() && count == 0) return std::chrono::microseconds{0};
    for (const auto& [suffix, scale] : units) {
        if (unit != suffix) continue;
        if (count > std::chrono::microseconds::max().count() / scale) return bad();
        return std::chrono::microseconds{count * scale};
    }
    return bad();
}

std::string format_duration(std::chrono::microseconds duration) {
    const long long us = duration.count();
    if (us == 0) return "0";
    for (auto it = units.rbegin(); it != units.rend(); ++it)
        if (us % it->second == 0) return fmt::format("{}{}", us / it->second, it->first);
    return fmt::format("{}us", us);
}

}  // namespace ioport
