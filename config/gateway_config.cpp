#include "config/gateway_config.hpp"

#include <algorithm>
#include <system_error>

#include <fmt/format.h>

namespace ioport::config {

namespace ip = boost::asio::ip;

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

std::string_view protocol_name(Protocol protocol) {
    switch (protocol) {
        case Protocol::ioport:
            return "ioport";
        case Protocol::id2:
            return "id2";
    }
    return "ioport";
}

namespace {

bool loopback(const std::string& host) {
    boost::system::error_code ec;
    const auto address = ip::make_address(host, ec);
    return host == "localhost" || (!ec && address.is_loopback());
}

// Every request names a user: a password, or a certificate the handshake verified.
bool authenticates(const HttpSettings& http) {
    return http.web &&
           (!http.web->users.empty() ||
            (http.web->tls && http.web->tls->client_auth == ClientAuth::require_and_verify));
}

}  // namespace

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
    if (config.http && !loopback(config.http->listen_host) && !authenticates(*config.http))
        found.push_back(fmt::format(
            "the HTTP side (http.listen \"{}\") is open to whoever reaches it: every value, the "
            "event log and the configuration's names. Give it an http.web_config_file with "
            "basic_auth_users or required client certificates (docs/http.md), or listen on "
            "127.0.0.1",
            host_port(config.http->listen_host, config.http->listen_port)));
    if (config.mqtt) password_in_clear(*config.mqtt, "mqtt");
    if (config.mqtt_json) password_in_clear(config.mqtt_json->connection, "mqtt_json");
    return found;
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
