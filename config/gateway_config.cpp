#include "config/gateway_config.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <span>
#include <sstream>
#include <system_error>
#include <utility>

#include <fmt/format.h>
#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/yaml.h>
#include <boost/asio/ip/network_v4.hpp>

#include "config/duration.hpp"
#include "config/number.hpp"
#include "config/tls_files.hpp"
#include "protocol/mqtt_id.hpp"
#include "protocol/mqtt_json.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::config {
namespace {

namespace ip = boost::asio::ip;
using std::chrono::microseconds;
// A parsed value, or the message that says what is allowed instead.
template <class T>
using Parsed = Expected<T, std::string>;

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

template <class IpNetwork>
Parsed<IpNetwork> without_host_bits(const IpNetwork& network, const std::string& text) {
    if (network == network.canonical()) return network;
    return Unexpected(fmt::format("'{}' has host bits set: did you mean {}?", text,
                                  network.canonical().to_string()));
}

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

struct Endpoint {
    std::string host;
    std::uint16_t port = 0;
};

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

constexpr std::string_view broker_help =
    "write mqtt://host[:port] or mqtts://host[:port], e.g. mqtt://127.0.0.1:1883";

// http.server_names: what a Host header names, as DNS spells it; no scheme, port or wildcard.
Parsed<std::string> server_name(const std::string& name) {
    constexpr std::size_t max_length = 253;
    const auto dns = [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
               c == '-' || c == '.' || c == '_';
    };
    if (name.empty() || name.size() > max_length || !std::ranges::all_of(name, dns))
        return Unexpected(fmt::format(
            "'{}' is not a host name: give one of 1..{} letters, digits, '-', '_' and '.', as a "
            "browser's address bar names this server, e.g. gateway.plant.example (no scheme, port "
            "or wildcard)",
            printable(name), max_length));
    return name;
}

Parsed<BrokerAddress> parse_broker(const std::string& text) {
    BrokerAddress broker;
    std::string_view rest = text;
    if (rest.starts_with("mqtts://")) {
        broker = {true, {}, 8883};
        rest.remove_prefix(8);
    } else if (rest.starts_with("mqtt://")) {
        rest.remove_prefix(7);
    } else {
        return Unexpected(fmt::format("'{}' is not an MQTT URL: {}", text, broker_help));
    }
    if (rest.ends_with('/')) rest.remove_suffix(1);
    // The port follows the last colon, after the closing bracket of an IPv6 address.
    const auto colon = rest.rfind(':');
    if (colon != std::string_view::npos && rest.find(']', colon) == std::string_view::npos) {
        const auto port = parse_decimal(rest.substr(colon + 1), 65535);
        if (!port || *port == 0)
            return Unexpected(fmt::format("'{}': the port must be 1..65535", text));
        broker.port = static_cast<std::uint16_t>(*port);
        rest = rest.substr(0, colon);
    }
    if (rest.starts_with('[') && rest.ends_with(']')) {
        const auto inner = rest.substr(1, rest.size() - 2);
        if (const auto address = parse_ip(std::string(inner)); !address || !address->is_v6())
            return Unexpected(fmt::format("'{}' is not an IPv6 address in brackets", text));
        broker.host = std::string(inner);
        return broker;
    }
    const bool name_like = !rest.empty() && std::ranges::all_of(rest, [](char c) {
        return std::isalnum(static_cast<unsigned char>(c)) != 0 || c == '-' || c == '.' || c == '_';
    });
    if (!name_like) return Unexpected(fmt::format("'{}' has no valid host: {}", text, broker_help));
    broker.host = std::string(rest);
    return broker;
}

// A secret in a file of its own: not readable by others (the o+r bit), writable by no one but
// its owner, not empty; one trailing newline is not part of it.
Parsed<std::string> read_secret(const std::string& path) {
    constexpr std::size_t max_secret = std::size_t{64} * 1024;
    auto secret = read_protected_file(path, Secrecy::secret, max_secret);
    if (!secret) return secret;
    if (secret->ends_with('\n')) secret->pop_back();
    if (secret->ends_with('\r')) secret->pop_back();
    if (secret->empty()) return Unexpected(fmt::format("{} is empty", path));
    return secret;
}

Parsed<std::string> readable_file(const std::string& path) {
    std::ifstream file(path);
    if (!file) return Unexpected(fmt::format("{}: cannot be read", path));
    return path;
}

// --- Scalars --------------------------------------------------------------------------------

// Quoted scalars are strings in YAML: `unit_id: "1"` is a wrong type, not a number.
bool quoted(const YAML::Node& value) {
    return value.Tag() == "!";
}

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
auto duration(microseconds min, microseconds max = microseconds::max()) {
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

Parsed<bool> boolean(const YAML::Node& value) {
    const std::string& text = value.Scalar();
    if (!quoted(value)) {
        if (text == "true" || text == "True" || text == "TRUE") return true;
        if (text == "false" || text == "False" || text == "FALSE") return false;
    }
    return Unexpected(fmt::format("'{}' is not allowed: use true or false, without quotes", text));
}

template <class E>
using Choices = std::span<const std::pair<std::string_view, E>>;

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

constexpr std::array<std::pair<std::string_view, WordOrder>, 2> word_orders{
    {{"big", WordOrder::big}, {"little", WordOrder::little}}};
constexpr std::array<std::pair<std::string_view, Stale>, 2> stale_choices{
    {{"exception", Stale::exception}, {"hold", Stale::hold}}};
constexpr std::array<std::pair<std::string_view, Protocol>, 2> protocols{
    {{"ioport", Protocol::ioport}, {"id2", Protocol::id2}}};
constexpr std::array<std::pair<std::string_view, OnShutdown>, 2> on_shutdown_choices{
    {{"keep", OnShutdown::keep}, {"initial", OnShutdown::initial}}};

Parsed<LogLevel> named_log_level(const YAML::Node& value) {
    if (const auto level = log_level_from_name(value.Scalar())) return *level;
    return Unexpected(
        fmt::format("'{}' is not allowed: use trace or debug or info or warn or "
                    "error or critical or off",
                    value.Scalar()));
}

Parsed<std::string> text_value(const YAML::Node& value) {
    return value.Scalar();
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

// A finite decimal number such as -20, 0.5 or 1e3.
Parsed<double> finite_number(const YAML::Node& value) {
    const std::string& text = value.Scalar();
    double number = 0;
    const auto* end = text.data() + text.size();
    const auto [at, ec] = std::from_chars(text.data(), end, number);
    if (quoted(value) || ec != std::errc() || at != end || !std::isfinite(number))
        return Unexpected(
            fmt::format("'{}' is not allowed: write a finite number such as -20 or 0.5, without "
                        "quotes",
                        printable(text, 40)));
    return number;
}

// A name or a unit (gateway.md §6.1).
auto tag_text(bool may_be_empty) {
    return [=](const YAML::Node& value) -> Parsed<std::string> {
        const std::string& text = value.Scalar();
        if (auto checked = gateway::check_tag_text(text, may_be_empty); !checked)
            return Unexpected(fmt::format("'{}' {}", printable(text, 80), checked.error().message));
        return text;
    };
}

Parsed<std::string> non_empty(const YAML::Node& value) {
    if (value.Scalar().empty()) return Unexpected(std::string("must not be empty"));
    return value.Scalar();
}

Parsed<ModuleType> module_type(const YAML::Node& value) {
    if (const auto type = module_type_from_name(value.Scalar())) return *type;
    return Unexpected(
        fmt::format("'{}' is not a module type: use dim16, dom16, acm3p, acm3c, "
                    "lim16, rgbdm, dccim, dcvim or mux8m",
                    value.Scalar()));
}

std::string output_value_help(ModuleType type) {
    switch (type) {
        case ModuleType::rgbdm:
            return "use a colour 0-7 or off, red, green, blue, cyan, magenta, yellow, white";
        case ModuleType::mux8m:
            return "use (pos << 8) | neg with pos and neg 0-7, e.g. 0x0102; 0x0707 = all "
                   "disconnected";
        case ModuleType::dom16:
            return "use the 16 outputs as one word 0..0xFFFF (bit k = output k), e.g. 0x00FF";
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;  // input modules take no initial value
    }
    return "";
}

// `initial` and `safe`: the module's holding register value; an rgbdm also takes a colour name.
auto output_value(ModuleType type, std::string_view key) {
    return [=](const YAML::Node& value) -> Parsed<std::uint16_t> {
        const std::string& text = value.Scalar();
        if (type == ModuleType::rgbdm)
            if (const auto colour = colour_from_name(text))
                return static_cast<std::uint16_t>(*colour);
        const auto number = parse_unsigned(text, 0xFFFF);
        if (number && quoted(value))
            return Unexpected(fmt::format(
                "\"{}\" is quoted, so it is text: write the number without quotes", text));
        if (!number)
            return Unexpected(fmt::format("'{}' is not {} {} value for {}: {}", text,
                                          key == "initial" ? "an" : "a", key, name(type),
                                          output_value_help(type)));
        const auto register_value = static_cast<std::uint16_t>(*number);
        if (auto ok = validate_output_value(type, register_value); !ok)
            return Unexpected(std::move(ok).error().message);
        return register_value;
    };
}

auto baud(std::optional<Protocol> protocol) {
    return [=](const YAML::Node& value) -> Parsed<int> {
        auto rate = integer(1, std::numeric_limits<int>::max())(value);
        if (!rate || !protocol) return rate;
        if (*protocol == Protocol::id2 && *rate != 9600)
            return Unexpected(fmt::format("{} is not allowed for protocol id2: use 9600", *rate));
        if (*protocol == Protocol::ioport && *rate != 38400 && *rate != 115200)
            return Unexpected(
                fmt::format("{} is not allowed for protocol ioport: use 38400 or 115200", *rate));
        return rate;
    };
}

// --- Walking the tree -----------------------------------------------------------------------

// yaml-cpp's lines are 0-based and -1 where unknown: this gives 1-based, 0 for unknown.
int line_of(const YAML::Node& node) {
    return node.Mark().line + 1;
}

std::string_view kind(const YAML::Node& node) {
    if (node.IsSequence()) return "a list";
    if (node.IsMap()) return "a mapping";
    if (node.IsNull()) return "no value";
    return "a single value";
}

struct Entry {
    YAML::Node value;
    // Of the key: an empty value or a block collection is marked on a later line.
    int line = 0;
};

// The keys of one mapping, checked against the ones allowed there.
struct Fields {
    std::string path;  // dotted, "" at the top
    int line = 0;      // of the mapping, for keys that are missing
    std::vector<std::pair<std::string, Entry>> entries;

    std::string key(std::string_view name) const {
        return path.empty() ? std::string(name) : fmt::format("{}.{}", path, name);
    }
    const Entry* find(std::string_view name) const {
        const auto it = std::ranges::find(entries, name, &std::pair<std::string, Entry>::first);
        return it == entries.end() ? nullptr : &it->second;
    }
    // Where a key is, or where it is missing from.
    int line_of(std::string_view name) const {
        const Entry* entry = find(name);
        return entry ? entry->line : line;
    }
};

using Keys = std::span<const std::string_view>;
constexpr std::array<std::string_view, 7> top_keys{"modbus", "http",        "mqtt",     "mqtt_json",
                                                   "links",  "on_shutdown", "log_level"};
constexpr std::array<std::string_view, 12> mqtt_keys{
    "broker",        "brokers", "group_id",  "edge_node_id",    "client_id", "username",
    "password_file", "ca_file", "keepalive", "primary_host_id", "deadband",  "store"};
constexpr std::array<std::string_view, 11> mqtt_json_keys{
    "broker",    "brokers",      "client_id", "username",         "password_file", "ca_file",
    "keepalive", "topic_prefix", "discovery", "discovery_prefix", "deadband"};
constexpr std::array<std::string_view, 3> store_keys{"path", "max_size", "forward_rate"};
constexpr std::array<std::string_view, 3> http_keys{"listen", "allow", "server_names"};
constexpr std::array<std::string_view, 10> modbus_keys{
    "listen", "max_connections", "idle_timeout",      "allow", "read_only", "word_order",
    "stale",  "keepalive",       "comm_loss_timeout", "tls"};
constexpr std::array<std::string_view, 8> tls_keys{"listen",       "certificate", "key",
                                                   "client_ca",    "client_crl",  "max_handshakes",
                                                   "default_role", "roles"};
constexpr std::array<std::string_view, 2> role_keys{"units", "access"};
constexpr std::array<std::pair<std::string_view, modbus_security::Access>, 2> accesses{
    {{"read", modbus_security::Access::read}, {"read_write", modbus_security::Access::read_write}}};
constexpr std::array<std::string_view, 10> link_keys{
    "name",    "protocol", "device",  "baud",     "unit_id",
    "timeout", "retries",  "modules", "identity", "max_pending_writes"};
constexpr std::array<std::string_view, 10> module_keys{"type",   "number",  "poll", "initial",
                                                       "safe",   "refresh", "name", "channels",
                                                       "inputs", "outputs"};
constexpr std::array<std::string_view, 4> channel_keys{"name", "unit", "scale", "range"};
// `identity:` keys by object id; MajorMinorRevision (0x02) is the version and not a key.
constexpr std::array<std::string_view, modbus::device_object_count> identity_keys{
    "vendor_name",  "product_code", "major_minor_revision", "vendor_url",
    "product_name", "model_name",   "user_application_name"};
constexpr std::size_t max_identity_length = 64;

constexpr std::string_view module_needed =
    "an ioport link needs at least one module, e.g. modules: [{ type: dim16, number: 0 }]";
constexpr int max_unit_id = 247;  // Modbus: 248..255 are reserved
// A refresh is one serial transaction per output module; faster than this it would crowd out
// the poll reads.
constexpr microseconds min_refresh = 10ms;

// Where something was first used, for the message at its second use.
struct FirstUse {
    std::string link;
    int line = 0;
};

class Loader {
  public:
    Loader(std::string file, const DeviceResolver& resolve)
        : file_(std::move(file)), resolve_(resolve) {}

    void add(int line, std::string key, std::string message) {
        errors_.push_back({file_, line, std::move(key), std::move(message)});
    }

    ConfigResult load(const YAML::Node& root) {
        GatewayConfig config;
        config.file = file_;
        read_root(root, config);
        if (errors_.empty()) return config;
        // Checks run per key, not in file order; the operator reads the file top to bottom.
        std::ranges::stable_sort(errors_, {}, &ConfigError::line);
        return Unexpected(std::move(errors_));
    }

  private:
    Fields fields(const YAML::Node& map, std::string path, Keys allowed);
    std::optional<Fields> mapping(const Entry& entry, std::string path, Keys allowed,
                                  std::string_view example);
    template <class T, class Parse>
    bool read(const Fields& fields, std::string_view name, std::string_view expected, T& out,
              Parse parse);
    void require(const Fields& fields, std::string_view name, std::string_view help);

    void read_root(const YAML::Node& root, GatewayConfig& config);
    void read_modbus(const Entry& entry, ModbusSettings& modbus);
    void read_tls(const Entry& entry, std::optional<TlsSettings>& tls);
    void read_tls_files(const Fields& fields, TlsSettings& tls);
    void read_roles(const Fields& fields, TlsSettings& tls);
    std::optional<modbus_security::Role> read_role(const Entry& entry, const std::string& path);
    void read_role_units(const Entry& entry, const std::string& path, modbus_security::Role& role);
    void check_role_units(const GatewayConfig& config);
    void read_allow(const Fields& fields, std::vector<Network>& allow);
    template <class T, class Parse>
    void read_list(const Fields& fields, std::string_view name, std::string_view list_example,
                   std::string_view item_example, Parse parse, std::vector<T>& items);
    void read_http(const Entry& entry, std::optional<HttpSettings>& http);
    void read_server_names(const Fields& fields, std::vector<std::string>& names);
    void read_mqtt(const Entry& entry, std::optional<MqttSettings>& mqtt);
    void read_mqtt_json(const Entry& entry, std::optional<MqttJsonSettings>& mqtt_json);
    // The keys of an MQTT connection, shared by mqtt: and mqtt_json: (client_id is the
    // section's own: its default differs).
    void read_connection(const Fields& fields, MqttSettings& connection);
    void read_brokers(const Fields& fields, MqttSettings& mqtt);
    void read_store(const Entry& entry, std::optional<StoreSettings>& store);
    void check_sparkplug_ids(const GatewayConfig& config);
    void check_topic_levels(const GatewayConfig& config);
    void check_client_ids(const GatewayConfig& config);
    void read_links(const Entry& entry, std::vector<LinkConfig>& links);
    void read_link(const YAML::Node& node, std::size_t index, std::vector<LinkConfig>& links);
    struct LinkOutcome {
        std::optional<Protocol> protocol;  // nullopt: missing or not valid
        bool unit_id_valid = true;         // else it is not checked for duplicates
    };
    LinkOutcome read_link_settings(const Fields& fields, std::size_t index, LinkConfig& link);
    void read_modules(const Fields& fields, std::optional<Protocol> protocol, LinkConfig& link);
    void read_identity(const Fields& fields, LinkConfig& link);
    std::optional<ModuleConfig> read_module(const YAML::Node& node, const std::string& path);
    void read_module_role(const Fields& fields, ModuleConfig& module);
    void read_tags(const Fields& fields, ModuleConfig& module);
    void read_channel(const Entry& entry, const std::string& path, ModuleType type,
                      gateway::ChannelTag& channel);
    std::optional<std::vector<double>> read_numbers(const Fields& fields, std::string_view name,
                                                    std::size_t count, std::string_view example);
    void read_points(const Entry& entry, const std::string& key, ModuleType type,
                     std::array<std::string, 16>& points);
    std::vector<std::pair<std::size_t, Entry>> indexed(const Entry& entry, const std::string& key,
                                                       std::size_t count, std::string_view noun,
                                                       std::string_view have);
    void check_unique(const Fields& fields, const LinkConfig& link, bool unit_id_valid);

    std::string file_;
    const DeviceResolver& resolve_;
    std::vector<ConfigError> errors_;
    std::map<std::string, FirstUse> names_;
    std::map<int, FirstUse> unit_ids_;
    std::map<std::string, FirstUse> devices_;  // by resolved path
    int json_client_id_line_ = 0;              // mqtt_json's, for check_client_ids()
    struct RoleUnit {
        int unit_id = 0;
        int line = 0;
        std::string key;
    };
    std::vector<RoleUnit> role_units_;  // checked against the links once they are read
};

Fields Loader::fields(const YAML::Node& map, std::string path, Keys allowed) {
    Fields result{std::move(path), line_of(map), {}};
    for (const auto& pair : map) {
        const int line = line_of(pair.first);
        const std::string name = pair.first.IsScalar() ? pair.first.Scalar() : "";
        const std::string key = result.key(name);
        if (!pair.first.IsScalar())
            add(line, result.path, fmt::format("a key must be a name, found {}", kind(pair.first)));
        else if (std::ranges::find(allowed, name) == allowed.end())
            add(line, key,
                fmt::format("unknown key: allowed here are {}", fmt::join(allowed, ", ")));
        else if (const Entry* first = result.find(name))
            add(line, key, fmt::format("duplicate key: already given at line {}", first->line));
        else
            result.entries.emplace_back(name, Entry{pair.second, line});
    }
    return result;
}

std::optional<Fields> Loader::mapping(const Entry& entry, std::string path, Keys allowed,
                                      std::string_view example) {
    if (entry.value.IsMap()) return fields(entry.value, std::move(path), allowed);
    add(entry.line, std::move(path),
        fmt::format("expected a mapping such as {}, found {}", example, kind(entry.value)));
    return std::nullopt;
}

// Reads key `name` into `out` if it is there: a missing key keeps the default.
template <class T, class Parse>
bool Loader::read(const Fields& fields, std::string_view name, std::string_view expected, T& out,
                  Parse parse) {
    const Entry* entry = fields.find(name);
    if (entry == nullptr) return false;
    if (!entry->value.IsScalar()) {
        add(entry->line, fields.key(name),
            fmt::format("expected {}, found {}", expected, kind(entry->value)));
        return false;
    }
    auto parsed = parse(entry->value);
    if (!parsed) {
        add(entry->line, fields.key(name), std::move(parsed).error());
        return false;
    }
    out = *std::move(parsed);
    return true;
}

void Loader::require(const Fields& fields, std::string_view name, std::string_view help) {
    if (fields.find(name) == nullptr)
        add(fields.line, fields.key(name), fmt::format("missing: {}", help));
}

void Loader::read_root(const YAML::Node& root, GatewayConfig& config) {
    if (root.IsNull()) {
        add(0, "links", "the file is empty: it needs at least one link under links");
        return;
    }
    if (!root.IsMap()) {
        add(line_of(root), "", "expected a mapping with the keys modbus and links");
        return;
    }
    const Fields top = fields(root, "", top_keys);
    if (const Entry* modbus = top.find("modbus")) read_modbus(*modbus, config.modbus);
    if (const Entry* http = top.find("http")) read_http(*http, config.http);
    require(top, "links", "the gateway needs at least one link");
    if (const Entry* links = top.find("links")) read_links(*links, config.links);
    if (const Entry* mqtt = top.find("mqtt")) read_mqtt(*mqtt, config.mqtt);
    if (config.mqtt) check_sparkplug_ids(config);
    if (const Entry* json = top.find("mqtt_json")) read_mqtt_json(*json, config.mqtt_json);
    if (config.mqtt_json) check_topic_levels(config);
    check_client_ids(config);
    check_role_units(config);
    read(top, "on_shutdown", "keep or initial", config.on_shutdown,
         choice<OnShutdown>(on_shutdown_choices));
    read(top, "log_level", "a log level", config.log_level, named_log_level);
}

void Loader::read_modbus(const Entry& entry, ModbusSettings& modbus) {
    if (entry.value.IsNull()) return;  // "modbus:" alone: every default
    const auto settings = mapping(entry, "modbus", modbus_keys, "{ listen: \"0.0.0.0:502\" }");
    if (!settings) return;
    const Fields& f = *settings;
    Endpoint listen{modbus.listen_host, modbus.listen_port};
    const Entry* off = f.find("listen");
    if (off != nullptr && off->value.IsScalar() && off->value.Scalar().empty()) {
        modbus.listen_host.clear();  // `listen: ""`: TLS only, or no Modbus at all
        modbus.listen_port = 0;
    } else if (read(f, "listen", "host:port, or \"\" for no plain Modbus TCP", listen,
                    [](const YAML::Node& value) { return parse_listen(value.Scalar()); })) {
        modbus.listen_host = listen.host;
        modbus.listen_port = listen.port;
    }
    read(f, "max_connections", "a number 1..65535", modbus.max_connections, integer(1, 65535));
    read(f, "idle_timeout", "a duration such as 5m, or 0 for never", modbus.idle_timeout,
         duration(microseconds{0}));
    read_allow(f, modbus.allow);
    read(f, "read_only", "true or false", modbus.read_only, boolean);
    read(f, "word_order", "big or little", modbus.word_order, choice<WordOrder>(word_orders));
    read(f, "stale", "exception or hold", modbus.stale, choice<Stale>(stale_choices));
    read(f, "keepalive", "a duration such as 60s, or 0 for off", modbus.keepalive,
         duration(microseconds{0}, 2h));
    read(f, "comm_loss_timeout", "a duration such as 10s, or 0 for off", modbus.comm_loss_timeout,
         duration(microseconds{0}, 24h));
    if (const Entry* tls = f.find("tls")) read_tls(*tls, modbus.tls);
    // Plain Modbus bypasses the roles: with TLS on, it runs only when asked for (gateway.md §5.6).
    modbus.listen_given = off != nullptr;
    if (modbus.tls && !modbus.listen_given) {
        modbus.listen_host.clear();
        modbus.listen_port = 0;
    }
}

void Loader::read_tls(const Entry& entry, std::optional<TlsSettings>& tls) {
    if (entry.value.IsNull()) return;  // "tls:" alone: no listen, so off
    const auto settings =
        mapping(entry, "modbus.tls", tls_keys, "{ listen: \"0.0.0.0:802\", certificate: ... }");
    if (!settings) return;
    const Fields& f = *settings;
    if (f.find("listen") == nullptr) return;  // absent = off (gateway.md §5.6)
    TlsSettings t;
    Endpoint listen{t.listen_host, t.listen_port};
    if (read(f, "listen", "host:port", listen,
             [](const YAML::Node& value) { return parse_listen(value.Scalar()); })) {
        t.listen_host = listen.host;
        t.listen_port = listen.port;
    }
    read_tls_files(f, t);
    read(f, "max_handshakes", "a number 1..1024", t.max_handshakes, integer(1, 1024));
    read_roles(f, t);
    read(f, "default_role", "a role name, or \"\" for none", t.default_role, text_value);
    if (!t.default_role.empty() && !t.roles.contains(t.default_role) && f.find("roles") != nullptr)
        add(f.line_of("default_role"), f.key("default_role"),
            fmt::format("'{}' is not one of the roles: give one of {}, or \"\" for none",
                        t.default_role, modbus_security::names(t.roles)));
    tls = std::move(t);
}

void Loader::read_tls_files(const Fields& f, TlsSettings& t) {
    require(f, "certificate", "the server's certificate (PEM), e.g. /etc/ioportd/tls/server.pem");
    require(f, "key",
            "the server certificate's private key (PEM), e.g. /etc/ioportd/tls/server.key");
    require(
        f, "client_ca",
        "the CA that signs the clients' certificates (PEM), e.g. /etc/ioportd/tls/client-ca.pem");
    const auto file = [&](std::string_view name, std::string& path, std::string& pem, auto reader) {
        if (!read(f, name, "a file's path", path, text_value)) return false;
        auto text = reader(path);
        if (!text) {
            add(f.line_of(name), f.key(name), std::move(text).error());
            return false;
        }
        pem = *std::move(text);
        return true;
    };
    const bool certificate =
        file("certificate", t.certificate, t.certificate_pem, read_certificates);
    const bool key = file("key", t.key, t.key_pem, read_private_key);
    const bool client_ca = file("client_ca", t.client_ca, t.client_ca_pem, read_certificates);
    if (client_ca)
        file("client_crl", t.client_crl, t.client_crl_pem,
             [&](const std::string& path) { return read_crl(path, t.client_ca_pem, t.client_ca); });
    if (certificate && key)
        if (auto pair = check_key_pair(t.certificate_pem, t.key_pem, t.key); !pair)
            add(f.line_of("key"), f.key("key"), std::move(pair).error());
}

void Loader::read_roles(const Fields& f, TlsSettings& t) {
    constexpr std::string_view example =
        "{ operator: { units: all, access: read_write }, viewer: { units: all, access: read } }";
    const Entry* entry = f.find("roles");
    if (entry == nullptr) {
        require(f, "roles", fmt::format("the roles clients may have, e.g. roles: {}", example));
        return;
    }
    if (!entry->value.IsMap() || entry->value.size() == 0) {
        add(entry->line, f.key("roles"),
            fmt::format("expected a mapping of role names such as {}, found {}", example,
                        entry->value.IsMap() ? "an empty mapping" : kind(entry->value)));
        return;
    }
    for (const auto& pair : entry->value) {
        const int line = line_of(pair.first);
        const std::string name = pair.first.IsScalar() ? pair.first.Scalar() : "";
        const std::string path = fmt::format("{}.{}", f.key("roles"), name);
        if (name.empty() || name.size() > modbus_security::max_role_length) {
            add(line, f.key("roles"),
                fmt::format("a role is a name of 1..{} characters",
                            modbus_security::max_role_length));
            continue;
        }
        if (t.roles.contains(name)) {
            add(line, path, "duplicate role");
            continue;
        }
        if (auto role = read_role({pair.second, line}, path)) t.roles.emplace(name, *role);
    }
}

std::optional<modbus_security::Role> Loader::read_role(const Entry& entry,
                                                       const std::string& path) {
    const auto settings = mapping(entry, path, role_keys, "{ units: all, access: read }");
    if (!settings) return std::nullopt;
    const Fields& f = *settings;
    modbus_security::Role role;
    require(f, "units", "all, or a list of unit ids such as [1, 2]");
    require(f, "access", "read or read_write");
    const std::size_t errors = errors_.size();
    read(f, "access", "read or read_write", role.access, choice<modbus_security::Access>(accesses));
    if (const Entry* units = f.find("units")) read_role_units(*units, path, role);
    if (errors_.size() != errors) return std::nullopt;
    return role;
}

void Loader::read_role_units(const Entry& entry, const std::string& path,
                             modbus_security::Role& role) {
    const std::string key = path + ".units";
    if (entry.value.IsScalar() && entry.value.Scalar() == "all" && !quoted(entry.value)) {
        role.units.set();
        return;
    }
    if (!entry.value.IsSequence() || entry.value.size() == 0) {
        add(entry.line, key,
            fmt::format("expected all, or a list of unit ids such as [1, 2], found {}",
                        entry.value.IsSequence() ? "an empty list" : kind(entry.value)));
        return;
    }
    std::size_t index = 0;
    for (const auto& item : entry.value) {
        const std::string item_key = fmt::format("{}[{}]", key, index++);
        const int line = std::max(line_of(item), entry.line);
        auto unit_id =
            item.IsScalar()
                ? integer(1, max_unit_id)(item)
                : Parsed<int>(Unexpected(fmt::format("expected a unit id, found {}", kind(item))));
        if (!unit_id) {
            add(line, item_key, std::move(unit_id).error());
            continue;
        }
        role.units.set(static_cast<std::size_t>(*unit_id));
        role_units_.push_back({*unit_id, line, item_key});
    }
}

// A unit no link has is a typing error: the role would grant nothing there.
void Loader::check_role_units(const GatewayConfig& config) {
    for (const auto& unit : role_units_) {
        if (std::ranges::any_of(
                config.links, [&](const LinkConfig& link) { return link.unit_id == unit.unit_id; }))
            continue;
        add(unit.line, unit.key,
            fmt::format("no link has unit id {}: give the unit_id of one of the links",
                        unit.unit_id));
    }
}

void Loader::read_http(const Entry& entry, std::optional<HttpSettings>& http) {
    http = HttpSettings{};
    if (entry.value.IsNull()) return;  // "http:" alone: every default
    const auto settings = mapping(entry, "http", http_keys, "{ listen: \"127.0.0.1:8502\" }");
    if (!settings) return;
    const Fields& f = *settings;
    read_allow(f, http->allow);
    read_server_names(f, http->server_names);
    Endpoint listen{http->listen_host, http->listen_port};
    const Entry* off = f.find("listen");
    if (off != nullptr && off->value.IsScalar() && off->value.Scalar().empty()) {
        http.reset();
        return;
    }
    if (read(f, "listen", "host:port, or \"\" for off", listen,
             [](const YAML::Node& value) { return parse_listen(value.Scalar()); })) {
        http->listen_host = listen.host;
        http->listen_port = listen.port;
    }
}

void Loader::read_server_names(const Fields& f, std::vector<std::string>& names) {
    read_list(f, "server_names", "a list of host names such as [\"gateway.plant.example\"]",
              "a host name", server_name, names);
}

void Loader::read_mqtt(const Entry& entry, std::optional<MqttSettings>& mqtt) {
    if (entry.value.IsNull()) return;  // "mqtt:" alone: no broker, so off
    const auto settings = mapping(entry, "mqtt", mqtt_keys,
                                  "{ broker: \"mqtt://127.0.0.1:1883\", group_id: plant1 }");
    if (!settings) return;
    const Fields& f = *settings;
    // absent = off (gateway.md §5.5)
    if (f.find("broker") == nullptr && f.find("brokers") == nullptr) return;
    MqttSettings m;
    read_connection(f, m);
    const auto sparkplug_id = [](const YAML::Node& value) -> Parsed<std::string> {
        if (auto checked = sparkplug::check_id(value.Scalar()); !checked)
            return Unexpected(checked.error().message);
        return value.Scalar();
    };
    require(f, "group_id", "the Sparkplug group of this edge node, e.g. group_id: plant1");
    read(f, "group_id", "a Sparkplug group id", m.group_id, sparkplug_id);
    require(f, "edge_node_id", "this box's Sparkplug edge node id, e.g. edge_node_id: box7");
    read(f, "edge_node_id", "a Sparkplug edge node id", m.edge_node_id, sparkplug_id);
    // Escaped, so that no two nodes share one ("a-b"/"c" and "a"/"b-c" once did).
    if (m.client_id.empty())
        m.client_id =
            fmt::format("ioportd-{}-{}", escaped_id(m.group_id), escaped_id(m.edge_node_id));
    read(f, "primary_host_id", "a Sparkplug host id", m.primary_host_id,
         [&](const YAML::Node& value) -> Parsed<std::string> {
             if (value.Scalar().empty()) return std::string();
             return sparkplug_id(value);
         });
    read(f, "deadband", "a number of engineering units, e.g. 0.5", m.deadband, non_negative);
    if (const Entry* store = f.find("store")) read_store(*store, m.store);
    mqtt = std::move(m);
}

void Loader::read_connection(const Fields& f, MqttSettings& m) {
    read_brokers(f, m);
    read(f, "client_id", "an MQTT client id", m.client_id, text_value);
    read(f, "username", "a user name", m.username, text_value);
    read(f, "password_file", "a file's path", m.password_file, text_value);
    if (!m.password_file.empty()) {
        if (auto secret = read_secret(m.password_file))
            m.password = *std::move(secret);
        else
            add(f.line_of("password_file"), f.key("password_file"), std::move(secret).error());
    }
    read(f, "ca_file", "a file's path", m.ca_file, text_value);
    if (!m.ca_file.empty()) {
        if (std::ranges::none_of(m.brokers, &BrokerAddress::tls))
            add(f.line_of("ca_file"), f.key("ca_file"),
                "a CA file is for mqtts:// brokers only: use mqtts:// or remove the key");
        else if (auto readable = readable_file(m.ca_file); !readable)
            add(f.line_of("ca_file"), f.key("ca_file"), std::move(readable).error());
    }
    read(f, "keepalive", "a duration such as 30s", m.keepalive, duration(5s, 65535s));
}

void Loader::read_mqtt_json(const Entry& entry, std::optional<MqttJsonSettings>& mqtt_json) {
    if (entry.value.IsNull()) return;  // "mqtt_json:" alone: no broker, so off
    const auto settings =
        mapping(entry, "mqtt_json", mqtt_json_keys,
                "{ broker: \"mqtt://127.0.0.1:1883\", topic_prefix: \"ioportd/box7\" }");
    if (!settings) return;
    const Fields& f = *settings;
    // absent = off (gateway.md §6.3)
    if (f.find("broker") == nullptr && f.find("brokers") == nullptr) return;
    MqttJsonSettings j;
    read_connection(f, j.connection);
    json_client_id_line_ = f.find("client_id") != nullptr ? f.line_of("client_id") : entry.line;
    const auto prefix = [](const YAML::Node& value) -> Parsed<std::string> {
        if (auto checked = mqtt_json::check_topic_prefix(value.Scalar()); !checked)
            return Unexpected(
                fmt::format("'{}' {}", printable(value.Scalar(), 80), checked.error().message));
        return value.Scalar();
    };
    read(f, "topic_prefix", "a topic prefix such as ioportd/box7", j.topic_prefix, prefix);
    read(f, "discovery", "true or false", j.discovery, boolean);
    read(f, "discovery_prefix", "a topic prefix such as homeassistant", j.discovery_prefix, prefix);
    read(f, "deadband", "a number of engineering units, e.g. 0.5", j.deadband, non_negative);
    // Escaped, so that no two prefixes share one ("plant/line1" and "plant_line1" once did), and
    // with one '-' where the Sparkplug node's has two, so that the sessions of the two sections,
    // of this gateway or another, never take each other's place.
    if (j.connection.client_id.empty())
        j.connection.client_id = fmt::format("ioportd-json_{}", escaped_id(j.topic_prefix));
    mqtt_json = std::move(j);
}

// `broker: URL` or `brokers: [URL, …]` (gateway.md §6.2), not both; each broker once.
void Loader::read_brokers(const Fields& f, MqttSettings& m) {
    if (f.find("broker") != nullptr && f.find("brokers") != nullptr) {
        add(f.line_of("brokers"), f.key("brokers"),
            "give broker (one) or brokers (a list), not both");
        return;
    }
    if (f.find("broker") != nullptr) {
        BrokerAddress broker;
        if (read(f, "broker", "an MQTT URL", broker,
                 [](const YAML::Node& value) { return parse_broker(value.Scalar()); }))
            m.brokers.push_back(broker);
        return;
    }
    const auto errors = errors_.size();
    read_list(
        f, "brokers", "a list such as [\"mqtt://10.0.0.5:1883\", \"mqtts://10.0.0.6:8883\"]",
        "an MQTT URL such as mqtt://10.0.0.5:1883",
        [](const std::string& text) { return parse_broker(text); }, m.brokers);
    const auto line = f.line_of("brokers");
    if (errors_.size() != errors) return;
    if (m.brokers.empty()) {
        add(line, f.key("brokers"), "name at least one broker, e.g. [\"mqtt://127.0.0.1:1883\"]");
    } else if (m.brokers.size() > max_brokers) {
        add(line, f.key("brokers"),
            fmt::format("{} brokers: at most {} are walked", m.brokers.size(), max_brokers));
    }
    for (auto it = m.brokers.begin(); it != m.brokers.end(); ++it)
        if (std::find(m.brokers.begin(), it, *it) != it)
            add(line, f.key("brokers"),
                fmt::format("{} is listed twice: name each broker once", to_string(*it)));
}

void Loader::read_store(const Entry& entry, std::optional<StoreSettings>& store) {
    if (entry.value.IsNull()) return;  // "store:" alone: no path, so none
    const auto settings = mapping(entry, "mqtt.store", store_keys,
                                  "{ path: /var/lib/ioportd/sparkplug, max_size: 64MiB }");
    if (!settings) return;
    const Fields& f = *settings;
    StoreSettings st;
    require(f, "path", "a directory for the store, e.g. path: /var/lib/ioportd/sparkplug");
    read(f, "path", "an absolute directory path", st.path,
         [](const YAML::Node& value) -> Parsed<std::string> {
             const auto& text = value.Scalar();
             if (!text.starts_with('/') || text.find('\0') != std::string::npos)
                 return Unexpected(fmt::format(
                     "'{}' is not an absolute path: write one such as /var/lib/ioportd/sparkplug",
                     printable(text)));
             return text;
         });
    read(f, "max_size", "a size such as 64MiB", st.max_size,
         [](const YAML::Node& value) -> Parsed<std::uint64_t> {
             const auto bytes = parse_bytes(value.Scalar(), max_store_size);
             if (!bytes || *bytes < min_store_size)
                 return Unexpected(fmt::format(
                     "'{}' is not a store size: write 1MiB..1GiB, e.g. 64MiB (KiB, MiB, GiB "
                     "are powers of 1024)",
                     printable(value.Scalar())));
             return *bytes;
         });
    read(f, "forward_rate", "a number 1..10000", st.forward_rate, integer(1, 10000));
    if (!st.path.empty()) store = std::move(st);
}

// Link names are part of Sparkplug device ids ("hub0.dim16.0"), so they must fit in a topic.
void Loader::check_sparkplug_ids(const GatewayConfig& config) {
    for (std::size_t i = 0; i < config.links.size(); ++i) {
        const auto& link = config.links[i];
        if (link.name.empty()) continue;  // reported already
        if (auto checked = sparkplug::check_id(link.name); !checked)
            add(link.line, fmt::format("links[{}].name", i),
                fmt::format("with mqtt on, a link name is part of Sparkplug device ids: {}",
                            checked.error().message));
    }
}

// Link names are a level of every plain MQTT topic ("ioportd/box7/hub0/dim16_0/state"), and,
// made safe (mqtt_json::safe_id), part of the Home Assistant ids of their modules' entities.
void Loader::check_topic_levels(const GatewayConfig& config) {
    std::map<std::string, std::size_t> ids;  // a safe id -> the first link that gives it
    for (std::size_t i = 0; i < config.links.size(); ++i) {
        const auto& link = config.links[i];
        if (link.name.empty()) continue;  // reported already
        if (auto checked = sparkplug::check_id(link.name); !checked && !config.mqtt)
            add(link.line, fmt::format("links[{}].name", i),
                fmt::format("with mqtt_json on, a link name is a topic level: {}",
                            checked.error().message));
        const auto [first, inserted] = ids.emplace(mqtt_json::safe_id(link.name), i);
        if (!inserted)
            add(link.line, fmt::format("links[{}].name", i),
                fmt::format("'{}' and links[{}].name '{}' are the same id '{}' in Home Assistant "
                            "(each character other than a letter, digit, _ or - becomes _): "
                            "rename one",
                            printable(link.name), first->second,
                            printable(config.links[first->second].name), first->first));
    }
}

// Two sessions of one client id take each other's place at a broker they share, each in turn.
void Loader::check_client_ids(const GatewayConfig& config) {
    if (!config.mqtt || !config.mqtt_json) return;
    const auto& spb = *config.mqtt;
    const auto& json = config.mqtt_json->connection;
    const auto shared = std::ranges::find_if(spb.brokers, [&](const BrokerAddress& broker) {
        return std::ranges::find(json.brokers, broker) != json.brokers.end();
    });
    if (spb.client_id == json.client_id && shared != spb.brokers.end())
        add(json_client_id_line_, "mqtt_json.client_id",
            fmt::format("'{}' is mqtt.client_id too, on the same broker {}: the two sessions "
                        "would take each other's place; give each its own",
                        printable(json.client_id), to_string(*shared)));
}

void Loader::read_allow(const Fields& f, std::vector<Network>& allow) {
    read_list(f, "allow", "a list of networks such as [\"10.0.0.0/8\", \"127.0.0.1\"]",
              "a network such as 10.0.0.0/8", parse_network, allow);
}

// A list of scalars, each parsed; `key:` alone or absent is the empty list. Every bad item is
// an error of its own, at its line.
template <class T, class Parse>
void Loader::read_list(const Fields& f, std::string_view name, std::string_view list_example,
                       std::string_view item_example, Parse parse, std::vector<T>& items) {
    const Entry* entry = f.find(name);
    if (entry == nullptr || entry->value.IsNull()) return;
    const std::string key = f.key(name);
    if (!entry->value.IsSequence()) {
        add(entry->line, key,
            fmt::format("expected {}, found {}", list_example, kind(entry->value)));
        return;
    }
    std::size_t index = 0;
    for (const auto& item : entry->value) {
        const std::string item_key = fmt::format("{}[{}]", key, index++);
        const int line = std::max(line_of(item), entry->line);
        if (!item.IsScalar()) {
            add(line, item_key, fmt::format("expected {}, found {}", item_example, kind(item)));
            continue;
        }
        auto parsed = parse(item.Scalar());
        if (parsed)
            items.push_back(*std::move(parsed));
        else
            add(line, item_key, std::move(parsed).error());
    }
}

void Loader::read_links(const Entry& entry, std::vector<LinkConfig>& links) {
    if (!entry.value.IsSequence() || entry.value.size() == 0) {
        add(entry.line, "links",
            fmt::format("expected a list of at least one link, found {}",
                        entry.value.IsSequence() ? "an empty list" : kind(entry.value)));
        return;
    }
    std::size_t index = 0;
    for (const auto& node : entry.value)
        read_link(node, index++, links);
}

void Loader::read_link(const YAML::Node& node, std::size_t index, std::vector<LinkConfig>& links) {
    const std::string path = fmt::format("links[{}]", index);
    if (!node.IsMap()) {
        add(line_of(node), path,
            fmt::format("expected a mapping with name, protocol and device, found {}", kind(node)));
        return;
    }
    const Fields f = fields(node, path, link_keys);
    LinkConfig link;
    link.line = f.line;
    const LinkOutcome outcome = read_link_settings(f, index, link);
    read_modules(f, outcome.protocol, link);
    read_identity(f, link);
    check_unique(f, link, outcome.unit_id_valid);
    links.push_back(std::move(link));
}

Loader::LinkOutcome Loader::read_link_settings(const Fields& f, std::size_t index,
                                               LinkConfig& link) {
    LinkOutcome outcome;
    require(f, "name", "every link needs a name, e.g. name: hub0");
    read(f, "name", "a name such as hub0", link.name, non_empty);
    require(f, "protocol", "use protocol: ioport (hub8u/hub8r) or protocol: id2");
    read(f, "protocol", "ioport or id2", outcome.protocol, choice<Protocol>(protocols));
    // Defaults that depend on the protocol, before the keys that may override them.
    const bool id2 = outcome.protocol == Protocol::id2;
    link.protocol = outcome.protocol.value_or(Protocol::ioport);
    link.baud = id2 ? 9600 : 115200;
    link.timeout = id2 ? microseconds{200ms} : microseconds{100ms};
    link.unit_id = static_cast<int>(index) + 1;
    require(f, "device", "the serial port, e.g. device: /dev/ttyUSB0");
    read(f, "device", "a path such as /dev/ttyUSB0", link.device, non_empty);
    read(f, "baud", "a baud rate", link.baud, baud(outcome.protocol));
    if (f.find("unit_id") == nullptr && link.unit_id > max_unit_id) {
        add(f.line, f.key("unit_id"),
            fmt::format("missing: the default {} (1 + the link's index) is over {}: set unit_id",
                        link.unit_id, max_unit_id));
        outcome.unit_id_valid = false;
    }
    if (f.find("unit_id") != nullptr)
        outcome.unit_id_valid =
            read(f, "unit_id", "a unit id 1..247", link.unit_id, integer(1, max_unit_id));
    read(f, "timeout", "a duration such as 100ms", link.timeout,
         duration(microseconds{1ms}, microseconds{10s}));
    read(f, "retries", "a number 0..10", link.retries, integer(0, 10));
    read(f, "max_pending_writes", "a number 1..1024", link.max_pending_writes, integer(1, 1024));
    return outcome;
}

void Loader::read_modules(const Fields& f, std::optional<Protocol> protocol, LinkConfig& link) {
    const Entry* entry = f.find("modules");
    const std::string key = f.key("modules");
    if (protocol == Protocol::id2) {
        if (entry != nullptr)
            add(entry->line, key,
                "an id2 link takes no modules (its Modbus map is fixed): remove "
                "the key");
        return;
    }
    if (entry == nullptr) {
        if (protocol) require(f, "modules", module_needed);
        return;
    }
    if (!entry->value.IsSequence() || entry->value.size() == 0) {
        add(entry->line, key,
            fmt::format("expected a list of at least one module, found {}: {}",
                        entry->value.IsSequence() ? "an empty list" : kind(entry->value),
                        module_needed));
        return;
    }
    std::map<int, int> first_line;  // slot → line: a duplicate is reported at its second use
    // Module names as resolved, so that a name equal to another module's default is caught too.
    std::map<std::string, std::size_t, std::less<>> names;  // → index in link.modules
    std::size_t index = 0;
    for (const auto& node : entry->value) {
        const std::string path = fmt::format("{}[{}]", key, index++);
        const auto module = read_module(node, path);
        if (!module) continue;
        const auto [first, fresh] = first_line.try_emplace(slot(module->address), module->line);
        if (!fresh) {
            add(module->line, path,
                fmt::format("{} is already configured on this link at line {}",
                            to_string(module->address), first->second));
            continue;
        }
        const auto [named, unique] = names.try_emplace(module->tags.name, link.modules.size());
        if (!unique) {
            const ModuleConfig& owner = link.modules[named->second];
            add(module->line, path + ".name",
                fmt::format("module name '{}' is already used on this link by {} at line {}: "
                            "names must be unique per link",
                            printable(module->tags.name, 80), to_string(owner.address),
                            owner.line));
        }
        link.modules.push_back(*module);
    }
}

std::optional<ModuleConfig> Loader::read_module(const YAML::Node& node, const std::string& path) {
    if (!node.IsMap()) {
        add(line_of(node), path,
            fmt::format("expected a mapping such as {{ type: dim16, number: 0 }}, found {}",
                        kind(node)));
        return std::nullopt;
    }
    const Fields f = fields(node, path, module_keys);
    require(f, "type", "the module type, e.g. type: dim16");
    require(f, "number", "the module's address switch 0..7, e.g. number: 0");
    std::optional<ModuleType> type;
    std::optional<std::uint8_t> number;
    read(f, "type", "a module type such as dim16", type, module_type);
    read(f, "number", "a number 0..7", number, integer<std::uint8_t>(0, 7));
    if (!type) return std::nullopt;  // which keys belong depends on the type
    ModuleConfig module{.address = {*type, number.value_or(0)}, .line = f.line, .tags = {}};
    read_module_role(f, module);
    read_tags(f, module);
    if (!number) return std::nullopt;
    return module;
}

void Loader::read_module_role(const Fields& f, ModuleConfig& module) {
    const ModuleType type = module.address.type;
    const auto misplaced = [&](std::string_view key, std::string_view why) {
        if (const Entry* entry = f.find(key)) add(entry->line, f.key(key), std::string(why));
    };
    if (is_output(type)) {
        misplaced("poll", fmt::format("poll is for input modules only: {} is an output module, "
                                      "its state is re-sent every refresh",
                                      name(type)));
        read(f, "initial", "a register value", module.initial, output_value(type, "initial"));
        module.safe = module.initial;
        read(f, "safe", "a register value", module.safe, output_value(type, "safe"));
        read(f, "refresh", "a duration such as 1s", module.refresh, duration(min_refresh));
        return;
    }
    for (const std::string_view key : {"initial", "safe", "refresh"})
        misplaced(key, fmt::format("{} is for output modules only (dom16, rgbdm, mux8m): {} is "
                                   "an input module",
                                   key, name(type)));
    read(f, "poll", "a duration such as 200ms, or 0 for every cycle", module.poll,
         duration(microseconds{0}));
}

// Names, units and scales (gateway.md §6.1), every default resolved here.
void Loader::read_tags(const Fields& f, ModuleConfig& module) {
    const ModuleType type = module.address.type;
    module.tags = gateway::default_tags(module.address);
    read(f, "name", "a name such as \"boiler 1\"", module.tags.name, tag_text(false));
    if (const Entry* channels = f.find("channels")) {
        const auto count = module.tags.channels.size();
        if (count == 0) {
            add(channels->line, f.key("channels"),
                fmt::format("channels is for analog modules only (acm3p, acm3c, dccim, dcvim): "
                            "{} has none",
                            name(type)));
        } else {
            const auto have = count == 1 ? fmt::format("{} has channel 0 only", name(type))
                                         : fmt::format("{} has channels 0, 1 and 2", name(type));
            for (const auto& [index, entry] :
                 indexed(*channels, f.key("channels"), count, "channel", have))
                read_channel(entry, fmt::format("{}.{}", f.key("channels"), index), type,
                             module.tags.channels[index]);
        }
    }
    const bool inputs = type == ModuleType::dim16 || type == ModuleType::lim16;
    if (const Entry* entry = f.find("inputs")) {
        if (inputs)
            read_points(*entry, f.key("inputs"), type, module.tags.points);
        else
            add(entry->line, f.key("inputs"),
                fmt::format("inputs names the inputs of dim16 and lim16: {}",
                            type == ModuleType::dom16
                                ? "dom16 is an output module, name its outputs with outputs:"
                                : fmt::format("{} has no digital inputs", name(type))));
    }
    if (const Entry* entry = f.find("outputs")) {
        if (type == ModuleType::dom16)
            read_points(*entry, f.key("outputs"), type, module.tags.points);
        else
            add(entry->line, f.key("outputs"),
                fmt::format("outputs names the outputs of dom16: {}",
                            inputs ? fmt::format("{} is an input module, name its inputs with "
                                                 "inputs:",
                                                 name(type))
                                   : fmt::format("{} has no digital outputs", name(type))));
    }
}

void Loader::read_channel(const Entry& entry, const std::string& path, ModuleType type,
                          gateway::ChannelTag& channel) {
    const auto f =
        mapping(entry, path, channel_keys,
                "{ name: \"supply temperature\", unit: \"°C\", scale: [0, 100, -20, 150] }");
    if (!f) return;
    read(*f, "name", "a name such as \"supply temperature\"", channel.name, tag_text(false));
    if (const auto scale = read_numbers(
            *f, "scale", 4, "[in_lo, in_hi, out_lo, out_hi], e.g. [0, 100, -20, 150]")) {
        const gateway::Scale s{(*scale)[0], (*scale)[1], (*scale)[2], (*scale)[3]};
        const auto bound = static_cast<double>(std::numeric_limits<float>::max());
        const auto fits = [&](std::uint16_t raw) {
            return std::abs(gateway::scaled(type, raw, s)) <= bound;
        };
        if (s.in_lo == s.in_hi)
            add(f->line_of("scale"), f->key("scale"),
                fmt::format("in_lo and in_hi must differ: both are {}", s.in_lo));
        else if (s.out_lo == s.out_hi)
            add(f->line_of("scale"), f->key("scale"),
                fmt::format("out_lo and out_hi must differ: the channel would always read {}",
                            s.out_lo));
        else if (!fits(0) || !fits(0xFFFF))
            add(f->line_of("scale"), f->key("scale"),
                "this scale maps the channel's readings beyond what a float32 register can hold");
        else
            channel.scale = s;
        channel.unit.clear();  // a scaled value is no longer in the unscaled unit
        channel.range = gateway::default_range(type, channel.scale);
    }
    read(*f, "unit", "a unit such as \"°C\", or \"\" for none", channel.unit, tag_text(true));
    if (const auto range = read_numbers(*f, "range", 2, "[lo, hi], e.g. [0, 6]")) {
        if ((*range)[0] < (*range)[1])
            channel.range = {(*range)[0], (*range)[1]};
        else
            add(f->line_of("range"), f->key("range"),
                fmt::format("[{}, {}]: lo must be less than hi", (*range)[0], (*range)[1]));
    }
}

// A flow list of `count` finite numbers, nullopt when the key is absent or wrong (reported).
std::optional<std::vector<double>> Loader::read_numbers(const Fields& f, std::string_view name,
                                                        std::size_t count,
                                                        std::string_view example) {
    const Entry* entry = f.find(name);
    if (entry == nullptr) return std::nullopt;
    if (!entry->value.IsSequence() || entry->value.size() != count) {
        add(entry->line, f.key(name),
            fmt::format("expected a list of {} numbers {}, found {}", count, example,
                        entry->value.IsSequence() ? fmt::format("{} items", entry->value.size())
                                                  : kind(entry->value)));
        return std::nullopt;
    }
    std::vector<double> numbers;
    for (const auto& item : entry->value) {
        auto number = item.IsScalar()
                          ? finite_number(item)
                          : Unexpected(fmt::format("expected a number, found {}", kind(item)));
        if (!number) {
            add(line_of(item), f.key(name), std::move(number).error());
            return std::nullopt;
        }
        numbers.push_back(*number);
    }
    return numbers;
}

void Loader::read_points(const Entry& entry, const std::string& key, ModuleType type,
                         std::array<std::string, 16>& points) {
    const bool inputs = type != ModuleType::dom16;
    for (const auto& [index, point] :
         indexed(entry, key, points.size(), inputs ? "input" : "output",
                 fmt::format("{} has {} 0..15", name(type), inputs ? "inputs" : "outputs"))) {
        const std::string path = fmt::format("{}.{}", key, index);
        if (!point.value.IsScalar()) {
            add(point.line, path,
                fmt::format("expected a name such as \"pump running\", found {}",
                            kind(point.value)));
            continue;
        }
        auto text = tag_text(false)(point.value);
        if (text)
            points[index] = *std::move(text);
        else
            add(point.line, path, std::move(text).error());
    }
}

// A mapping by index, such as `channels: { 0: ..., 2: ... }`: each index once, below `count`.
std::vector<std::pair<std::size_t, Entry>> Loader::indexed(const Entry& entry,
                                                           const std::string& key,
                                                           std::size_t count, std::string_view noun,
                                                           std::string_view have) {
    std::vector<std::pair<std::size_t, Entry>> items;
    if (!entry.value.IsMap()) {
        add(entry.line, key,
            fmt::format("expected a mapping by {} number such as {{ 0: ... }}, found {}", noun,
                        kind(entry.value)));
        return items;
    }
    std::map<std::size_t, int> first_line;
    for (const auto& pair : entry.value) {
        const int line = line_of(pair.first);
        const std::string text = pair.first.IsScalar() ? pair.first.Scalar() : "";
        const auto index = pair.first.IsScalar() && !quoted(pair.first)
                               ? parse_unsigned(text, count - 1)
                               : std::nullopt;
        if (!index) {
            add(line, key,
                fmt::format("'{}' is not a {} number: {}", printable(text, 40), noun, have));
            continue;
        }
        const auto [first, fresh] = first_line.try_emplace(*index, line);
        if (fresh)
            items.emplace_back(*index, Entry{pair.second, line});
        else
            add(line, fmt::format("{}.{}", key, *index),
                fmt::format("duplicate {}: {} {} is already given at line {}", noun, noun, *index,
                            first->second));
    }
    return items;
}

void Loader::read_identity(const Fields& link_fields, LinkConfig& link) {
    const Entry* entry = link_fields.find("identity");
    if (entry == nullptr || entry->value.IsNull()) return;
    const auto f = mapping(*entry, link_fields.key("identity"), identity_keys,
                           "{ model_name: hub8u, user_application_name: press line 2 }");
    if (!f) return;
    const auto text = [](const YAML::Node& value) -> Parsed<std::string> {
        const std::string& s = value.Scalar();
        if (s.empty() || s.size() > max_identity_length)
            return Unexpected(fmt::format("'{}' has {} characters: use 1 to {}", s, s.size(),
                                          max_identity_length));
        if (!std::ranges::all_of(s, [](char c) { return c >= 0x20 && c <= 0x7E; }))
            return Unexpected(fmt::format(
                "'{}' has a character that is not printable ASCII: use letters, digits, spaces "
                "and punctuation",
                printable(s)));
        return s;
    };
    for (std::size_t id = 0; id < identity_keys.size(); ++id) {
        if (id == static_cast<std::size_t>(modbus::DeviceObject::major_minor_revision)) {
            if (const Entry* revision = f->find(identity_keys[id]))
                add(revision->line, f->key(identity_keys[id]),
                    "MajorMinorRevision is the ioportd version and cannot be set: remove the key");
            continue;
        }
        read(*f, identity_keys[id], "printable text", link.identity[id], text);
    }
}

void Loader::check_unique(const Fields& f, const LinkConfig& link, bool unit_id_valid) {
    const FirstUse me{link.name.empty() ? f.path : fmt::format("link '{}'", link.name), f.line};
    if (!link.name.empty()) {
        // Unique ignoring case: the name is part of Sparkplug metric names and device ids, and
        // hosts may not tell hub0 from Hub0 (Sparkplug 3.0, case-sensitivity-metric-names).
        auto folded = link.name;
        std::ranges::transform(folded, folded.begin(),
                               [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
        const auto [first, fresh] = names_.try_emplace(folded, me);
        if (!fresh)
            add(f.line_of("name"), f.key("name"),
                fmt::format("link name '{}' is already used at line {}: names must be unique, "
                            "and unique ignoring case",
                            link.name, first->second.line));
    }
    if (unit_id_valid) {
        const auto [first, fresh] = unit_ids_.try_emplace(link.unit_id, me);
        if (!fresh)
            add(f.line_of("unit_id"), f.key("unit_id"),
                fmt::format("unit id {}{} is already used by {} (line {}): each link needs its "
                            "own",
                            link.unit_id,
                            f.find("unit_id") ? "" : " (the default: 1 + the link's index)",
                            first->second.link, first->second.line));
    }
    if (!link.device.empty()) {
        // Two spellings of one port (a by-id symlink and /dev/ttyUSB0) are one port.
        const std::string resolved = resolve_(link.device);
        const auto [first, fresh] = devices_.try_emplace(resolved, me);
        if (!fresh)
            add(f.line_of("device"), f.key("device"),
                fmt::format("device {} is already used by {} (line {}){}", link.device,
                            first->second.link, first->second.line,
                            resolved == link.device ? "" : fmt::format(": both are {}", resolved)));
    }
}

// --- Documents ------------------------------------------------------------------------------

// yaml-cpp 0.7's LoadAll never returns on some invalid text, a ',' outside [ ] or { } for one
// (jbeder/yaml-cpp#1040, fixed upstream after 0.8): its parser stops consuming the text and
// yields the same empty document over and over, and LoadAll keeps each one until memory runs
// out. So the documents are counted here, a bounded number of them, and one that starts where the
// previous one did is a syntax error.
class DocumentStarts : public YAML::EventHandler {
  public:
    struct Document {
        YAML::Mark start;
        std::optional<YAML::Mark> root;  // of its root node, where LoadAll's Node has its mark
    };
    std::vector<Document> documents;

    void OnDocumentStart(const YAML::Mark& mark) override { documents.push_back({mark, {}}); }
    void OnDocumentEnd() override {}
    void OnNull(const YAML::Mark& mark, YAML::anchor_t) override { node(mark); }
    void OnAlias(const YAML::Mark& mark, YAML::anchor_t) override { node(mark); }
    void OnScalar(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                  const std::string&) override {
        node(mark);
    }
    void OnSequenceStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                         YAML::EmitterStyle::value) override {
        node(mark);
    }
    void OnSequenceEnd() override {}
    void OnMapStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                    YAML::EmitterStyle::value) override {
        node(mark);
    }
    void OnMapEnd() override {}

  private:
    void node(const YAML::Mark& mark) {
        if (!documents.empty() && !documents.back().root) documents.back().root = mark;
    }
};

struct Documents {
    std::optional<YAML::Mark> second;    // the root of a second document
    std::optional<YAML::Mark> stuck_at;  // where the parser stopped making progress
};

Documents scan_documents(const std::string& text) {
    std::istringstream stream(text);
    YAML::Parser parser(stream);
    DocumentStarts starts;
    auto& documents = starts.documents;
    // Three are enough to tell a second document from a parser stuck at the first or second.
    while (documents.size() < 3 && parser.HandleNextDocument(starts)) {
        const auto count = documents.size();
        if (count >= 2 && documents[count - 1].start.pos == documents[count - 2].start.pos)
            return {std::nullopt, documents[count - 1].start};
    }
    if (documents.size() < 2) return {};
    return {documents[1].root.value_or(documents[1].start), std::nullopt};
}

std::string stuck_message(const std::string& text, const YAML::Mark& mark) {
    const auto at = static_cast<std::size_t>(std::max(mark.pos, 0));
    if (at < text.size() && text[at] == ',')
        return fmt::format(
            "YAML syntax error at column {}: a ',' separates the items of a [ ] or {{ }} "
            "list, and there is none here",
            mark.column + 1);
    return fmt::format("YAML syntax error at column {}: no value can start here", mark.column + 1);
}

// The configuration grants rights too (roles, the files it names): read as read_protected_file
// reads them. Its messages begin with the path, which the configuration's error names already.
Parsed<std::string> read_config_file(const std::string& path) {
    constexpr std::size_t max_config_size = std::size_t{4} * 1024 * 1024;
    auto text = read_protected_file(path, Secrecy::public_file, max_config_size);
    if (text) return text;
    std::string message = std::move(text).error();
    if (message.starts_with(path)) message.erase(0, path.size());
    if (message.starts_with(": ")) return Unexpected("cannot read the file" + message);
    if (message.starts_with(' ')) message.erase(0, 1);
    return Unexpected(std::move(message));
}

}  // namespace

std::string_view to_string(LogLevel level) {
    const auto name = spdlog::level::to_string_view(level);
    return {name.data(), name.size()};
}

std::optional<LogLevel> log_level_from_name(std::string_view name) {
    // from_str() answers off for a name it does not know.
    const auto level = spdlog::level::from_str(std::string(name));
    if (level == spdlog::level::off && name != "off") return std::nullopt;
    return level;
}

std::string to_string(const ConfigError& error) {
    std::string text = error.file;
    if (error.line > 0) text += fmt::format(":{}", error.line);
    text += ": ";
    if (!error.key.empty()) text += error.key + ": ";
    return text + error.message;
}

std::string resolve_device(const std::string& device) {
    std::error_code error;
    const auto resolved = std::filesystem::weakly_canonical(device, error);
    return error ? device : resolved.string();
}

ConfigResult parse_config(std::string_view yaml, const std::string& file,
                          const DeviceResolver& resolve) {
    Loader loader(file, resolve);
    const std::string text(yaml);
    // yaml-cpp reports syntax errors by throwing; from here on they are values.
    try {
        const auto documents = scan_documents(text);
        if (documents.stuck_at) {
            const auto& mark = *documents.stuck_at;
            return Unexpected(
                std::vector{ConfigError{file, mark.line + 1, "", stuck_message(text, mark)}});
        }
        if (documents.second)
            loader.add(documents.second->line + 1, "",
                       "one YAML document only: remove the second '---' and what follows");
        return loader.load(YAML::Load(text));  // the first document, or null for none
    } catch (const YAML::Exception& e) {
        return Unexpected(std::vector{
            ConfigError{file, e.mark.line + 1, "", fmt::format("YAML syntax error: {}", e.msg)}});
    }
}

std::vector<std::string> warnings(const GatewayConfig& config) {
    std::vector<std::string> found;
    const auto& modbus = config.modbus;
    if (modbus.plain() && modbus.tls) {
        found.push_back(fmt::format(
            "plain Modbus TCP (modbus.listen \"{}\") bypasses the roles of Modbus/TCP "
            "Security: any client that reaches it may {} every unit. Remove modbus.listen, or set "
            "it to \"\", to serve TLS clients only",
            host_port(modbus.listen_host, modbus.listen_port),
            modbus.read_only ? "read" : "read and write"));
    }
    const auto password_in_clear = [&](const MqttSettings& connection, std::string_view section) {
        if (connection.password.empty()) return;
        for (const auto& broker : connection.brokers)
            if (!broker.tls)
                found.push_back(fmt::format(
                    "the MQTT password ({}.password_file) goes to the broker {} unencrypted "
                    "over mqtt://, readable by anyone on the way: use mqtts://",
                    section, broker.host));
    };
    if (config.mqtt) password_in_clear(*config.mqtt, "mqtt");
    if (config.mqtt_json) password_in_clear(config.mqtt_json->connection, "mqtt_json");
    return found;
}

ConfigResult load_config(const std::filesystem::path& path, const DeviceResolver& resolve) {
    auto text = read_config_file(path.string());
    if (!text)
        return Unexpected(std::vector{ConfigError{path.string(), 0, "", std::move(text).error()}});
    return parse_config(*text, path.string(), resolve);
}

bool contains(const Network& network, const ip::address& client) {
    // As IPv6, like the networks. A link-local client's zone (fe80::1%eth0) takes no part.
    const auto address = client.is_v4() ? ip::make_address_v6(ip::v4_mapped, client.to_v4())
                                        : ip::address_v6(client.to_v6().to_bytes());
    const ip::network_v6 host(address, 128);
    // is_subnet_of() is true for strictly smaller networks only: a /128 is its own host.
    return host == network.network || host.is_subnet_of(network.network);
}

std::string to_string(const BrokerAddress& broker) {
    return fmt::format("{}://{}", broker.tls ? "mqtts" : "mqtt",
                       host_port(broker.host, broker.port));
}

std::string host_port(std::string_view host, unsigned port) {
    return host.find(':') != std::string_view::npos ? fmt::format("[{}]:{}", host, port)
                                                    : fmt::format("{}:{}", host, port);
}

bool same_tags(const LinkConfig& a, const LinkConfig& b) {
    return std::ranges::equal(a.modules, b.modules, {}, &ModuleConfig::tags, &ModuleConfig::tags);
}

}  // namespace ioport::config
