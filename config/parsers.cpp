#include "config/parsers.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <system_error>

#include <boost/asio/ip/network_v4.hpp>

namespace ioport::config::detail {

namespace ip = boost::asio::ip;

// --- IP addresses ---------------------------------------------------------------------------

// An IP address literal, IPv4 or IPv6, as inet_pton(3) reads it: no zone ("fe80::1%eth0"),
// which Asio would take and an allow list or a listening address has no use for.
std::optional<ip::address> parse_ip(const std::string& text) {
    boost::system::error_code error;
    const auto address = ip::make_address(text, error);
    if (error || text.find('%') != std::string::npos) return std::nullopt;
    return address;
}

// Digits only: a port or a prefix length is never written in hex.
std::optional<unsigned long> parse_decimal(std::string_view text, unsigned long max) {
    if (text.empty() || !std::ranges::all_of(text, [](char c) { return c >= '0' && c <= '9'; }))
        return std::nullopt;
    return parse_unsigned(text, max);
}

namespace {

template <class IpNetwork>
Parsed<IpNetwork> without_host_bits(const IpNetwork& network, const std::string& text) {
    if (network == network.canonical()) return network;
    return Unexpected(fmt::format("'{}' has host bits set: did you mean {}?", text,
                                  network.canonical().to_string()));
}

}  // namespace

// The network is built by Asio from the address and the prefix length, each checked here: Asio's
// make_network_v4/v6 want the "/n" that a bare address lacks, and read n with atoi, which takes
// 10.0.0.0/4294967304 for 10.0.0.0/8.
Parsed<Network> parse_network(const std::string& text) {
    const auto slash = text.find('/');
    const auto address = parse_ip(text.substr(0, slash));
    if (!address)
        return Unexpected(
            fmt::format("'{}' is not an IP network: write a.b.c.d/n, an IPv6 network "
                        "such as fd00::/8, or a bare address",
                        text));
    const unsigned max_prefix = address->is_v4() ? 32 : 128;
    unsigned long prefix = max_prefix;
    if (slash != std::string::npos) {
        const auto length = parse_decimal(std::string_view(text).substr(slash + 1), max_prefix);
        if (!length)
            return Unexpected(
                fmt::format("'{}': the prefix length after / must be 0..{}", text, max_prefix));
        prefix = *length;
    }
    const auto length = static_cast<unsigned short>(prefix);
    if (address->is_v6()) {
        auto network = without_host_bits(ip::network_v6(address->to_v6(), length), text);
        if (!network) return Unexpected(std::move(network).error());
        return Network{*network, text};
    }
    auto network = without_host_bits(ip::network_v4(address->to_v4(), length), text);
    if (!network) return Unexpected(std::move(network).error());
    // a.b.c.d/n as ::ffff:a.b.c.d/(96 + n): one comparison serves IPv4 clients, IPv4 clients of
    // an IPv6 socket (which are ::ffff:a.b.c.d) and IPv6 clients.
    return Network{ip::network_v6(ip::make_address_v6(ip::v4_mapped, network->address()),
                                  static_cast<unsigned short>(96 + length)),
                   text};
}

namespace {

constexpr std::string_view listen_help = "write host:port, e.g. 0.0.0.0:502 or [::]:502";

Parsed<std::string> parse_listen_host(const std::string& host) {
    if (host.starts_with('[')) {
        const auto inner = host.substr(1, host.size() - 2);
        if (const auto address = parse_ip(inner);
            host.ends_with(']') && address && address->is_v6())
            return inner;
        return Unexpected(
            fmt::format("'{}' is not an IPv6 address in brackets: {}", host, listen_help));
    }
    // Resolving names would make the address depend on DNS at start-up; localhost is certain.
    if (host == "localhost") return std::string("127.0.0.1");
    if (host.find(':') != std::string::npos)
        return Unexpected(fmt::format("IPv6 addresses go in brackets: [{}]:502", host));
    if (const auto address = parse_ip(host); address && address->is_v4()) return host;
    return Unexpected(
        fmt::format("'{}' is not an IP address: use an IP address such as 0.0.0.0 "
                    "(every IPv4 interface), 127.0.0.1 or [::]; names are not "
                    "looked up",
                    host));
}

}  // namespace

Parsed<Endpoint> parse_listen(const std::string& text) {
    // The port follows the last colon, after the closing bracket of an IPv6 address.
    const auto colon = text.rfind(':');
    if (colon == std::string::npos || text.find(']', colon) != std::string::npos)
        return Unexpected(fmt::format("'{}' has no port: {}", text, listen_help));
    const auto port = parse_decimal(std::string_view(text).substr(colon + 1), 65535);
    // Port 0 lets the system pick a free port, which the start-up log names (for tests).
    if (!port) return Unexpected(fmt::format("'{}': the port must be 0..65535", text));
    auto host = parse_listen_host(text.substr(0, colon));
    if (!host) return Unexpected(std::move(host).error());
    return Endpoint{*std::move(host), static_cast<std::uint16_t>(*port)};
}

// --- Scalars --------------------------------------------------------------------------------

// Quoted scalars are strings in YAML: `unit_id: "1"` is a wrong type, not a number.
bool quoted(const YAML::Node& value) {
    return value.Tag() == "!";
}

Parsed<bool> boolean(const YAML::Node& value) {
    const std::string& text = value.Scalar();
    if (!quoted(value)) {
        if (text == "true" || text == "True" || text == "TRUE") return true;
        if (text == "false" || text == "False" || text == "FALSE") return false;
    }
    return Unexpected(fmt::format("'{}' is not allowed: use true or false, without quotes", text));
}

Parsed<std::string> text_value(const YAML::Node& value) {
    return value.Scalar();
}

Parsed<std::string> user_name(const std::string& name) {
    constexpr std::size_t max_length = 64;
    const bool valid =
        !name.empty() && name.size() <= max_length && std::ranges::all_of(name, [](char c) {
            return static_cast<unsigned char>(c) > 0x20 && c != 0x7F && c != ':';
        });
    if (valid) return name;
    return Unexpected(
        fmt::format("'{}' is not a user name: 1..{} printable characters without "
                    "spaces or ':'",
                    printable(name), max_length));
}

// A decimal number >= 0, such as 0.5 or 2.
Parsed<double> non_negative(const YAML::Node& value) {
    const std::string& text = value.Scalar();
    double number = 0;
    const auto* end = text.data() + text.size();
    const auto [at, ec] = std::from_chars(text.data(), end, number);
    if (quoted(value) || ec != std::errc() || at != end || !std::isfinite(number) || number < 0)
        return Unexpected(
            fmt::format("'{}' is not allowed: write a number of at least 0, e.g. 0.5", text));
    return number;
}

}  // namespace ioport::config::detail
