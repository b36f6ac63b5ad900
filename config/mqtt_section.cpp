#include "config/loader.hpp"

#include <cctype>
#include <fstream>

#include "config/tls_files.hpp"
#include "protocol/mqtt_id.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 15> mqtt_keys{
    "broker",   "brokers",       "group_id",  "edge_node_id",    "client_id",
    "username", "password_file", "ca_file",   "keepalive",       "protocol",
    "deadband", "store",         "templates", "primary_host_id", "device_id_separator"};
constexpr std::array<std::string_view, 3> store_keys{"path", "max_size", "forward_rate"};

constexpr std::string_view broker_help =
    "write mqtt://host[:port] or mqtts://host[:port], e.g. mqtt://127.0.0.1:1883";

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

// Quoted or not: YAML reads an unquoted 5 as the text "5" too.
Parsed<MqttProtocol> mqtt_protocol(const YAML::Node& value) {
    const std::string& text = value.Scalar();
    for (const auto protocol : {MqttProtocol::automatic, MqttProtocol::v5, MqttProtocol::v311})
        if (text == to_string(protocol)) return protocol;
    return Unexpected(
        fmt::format("'{}' is not an MQTT version: use auto (5, or 3.1.1 for a broker "
                    "that does not take 5), \"5\" or \"3.1.1\"",
                    text));
}

Parsed<std::string> readable_file(const std::string& path) {
    std::ifstream file(path);
    if (!file) return Unexpected(fmt::format("{}: cannot be read", path));
    return path;
}

}  // namespace

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
    read(f, "templates", "true or false", m.templates, boolean);
    read(f, "device_id_separator", "one of . - _ :", m.device_id_separator,
         [](const YAML::Node& value) -> Parsed<char> {
             const std::string& text = value.Scalar();
             if (text.size() == 1 &&
                 sparkplug::device_id_separators.find(text[0]) != std::string_view::npos)
                 return text[0];
             return Unexpected(fmt::format(
                 "'{}' is not a separator of device ids: use \".\" (the default), \"-\", \"_\" "
                 "or \":\"",
                 printable(text)));
         });
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
    read(f, "protocol", "auto, \"5\" or \"3.1.1\"", m.protocol, mqtt_protocol);
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

}  // namespace ioport::config::detail
