// The parsers the sections of the loader share (internal to config/): IP addresses, networks
// and listen endpoints from text, and YAML scalars into values, each with the message that says
// what is allowed instead. Each returns a value or that message; the Loader adds file, line and
// key.
#pragma once

#include <chrono>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>
#include <boost/asio/ip/address.hpp>

#include "config/duration.hpp"
#include "config/gateway_config.hpp"
#include "config/number.hpp"

namespace ioport::config::detail {

using std::chrono::microseconds;
// A parsed value, or the message that says what is allowed instead.
template <class T>
using Parsed = Expected<T, std::string>;

// --- IP addresses ---------------------------------------------------------------------------

// An IP address literal, IPv4 or IPv6, without a zone.
std::optional<boost::asio::ip::address> parse_ip(const std::string& text);
// Digits only, 0..max.
std::optional<unsigned long> parse_decimal(std::string_view text, unsigned long max);
// An item of `allow`: a.b.c.d/n, an IPv6 network such as fd00::/8, or a bare address.
Parsed<Network> parse_network(const std::string& text);

// A `listen` key: an IP literal (IPv6 without its brackets) and a port (0: the system picks).
struct Endpoint {
    std::string host;
    std::uint16_t port = 0;
};
// host:port, e.g. 0.0.0.0:502 or [::]:502; localhost is the one name taken.
Parsed<Endpoint> parse_listen(const std::string& text);

// --- Scalars --------------------------------------------------------------------------------

// Whether a scalar was written in quotes.
bool quoted(const YAML::Node& value);

// A whole number min..max, unquoted.
template <class Int>
auto integer(Int min, Int max) {
    return [=](const YAML::Node& value) -> Parsed<Int> {
        const std::string& text = value.Scalar();
        if (quoted(value))
            return Unexpected(
                fmt::format("\"{}\" is quoted, so it is text: write a number {}..{} without quotes",
                            text, min, max));
        const bool negative = text.starts_with('-');
        const auto number = parse_unsigned(std::string_view(text).substr(negative ? 1 : 0),
                                           std::numeric_limits<unsigned long>::max());
        if (!number)
            return Unexpected(
                fmt::format("'{}' is not a whole number: use {}..{}", text, min, max));
        if (negative || *number < static_cast<unsigned long>(min) ||
            *number > static_cast<unsigned long>(max))
            return Unexpected(fmt::format("{} is out of range: use {}..{}", text, min, max));
        return static_cast<Int>(*number);
    };
}

// `max` of microseconds::max() means no upper bound.
inline auto duration(microseconds min, microseconds max = microseconds::max()) {
    return [=](const YAML::Node& value) -> Parsed<microseconds> {
        const auto parsed = parse_duration(value.Scalar());
        if (!parsed) return Unexpected(parsed.error().message);
        if (max == microseconds::max() && *parsed < min)
            return Unexpected(fmt::format("{} is too short: use at least {}", value.Scalar(),
                                          format_duration(min)));
        if (*parsed < min || *parsed > max)
            return Unexpected(fmt::format("{} is out of range: use {}..{}", value.Scalar(),
                                          format_duration(min), format_duration(max)));
        return *parsed;
    };
}

// true or false, unquoted.
Parsed<bool> boolean(const YAML::Node& value);

template <class E>
using Choices = std::span<const std::pair<std::string_view, E>>;

// One of `choices`, by its name.
template <class E>
auto choice(Choices<E> choices) {
    return [=](const YAML::Node& value) -> Parsed<E> {
        for (const auto& [text, e] : choices)
            if (text == value.Scalar()) return e;
        std::string names;
        for (const auto& [text, e] : choices)
            names += fmt::format("{}{}", names.empty() ? "" : " or ", text);
        return Unexpected(fmt::format("'{}' is not allowed: use {}", value.Scalar(), names));
    };
}

// Any text, as written.
Parsed<std::string> text_value(const YAML::Node& value);
// A user of the HTTP side (gateway.md §7.1): 1..64 printable bytes, no space or ':' (RFC 7617
// splits there).
Parsed<std::string> user_name(const std::string& name);
// A number of at least 0, unquoted.
Parsed<double> non_negative(const YAML::Node& value);

}  // namespace ioport::config::detail
