#include "config/gateway_config.hpp"

#include <algorithm>
#include <map>
#include <system_error>

#include <fmt/format.h>
#include <fmt/ranges.h>

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

// The cost of a bcrypt hash ("$2y$10$…": 10), which the loader checked.
int bcrypt_cost(const std::string& hash) {
    return (hash[4] - '0') * 10 + (hash[5] - '0');
}

// What the web configuration's users cost each check, and whether their passwords cross the
// network readable (gateway.md §7.5).
void web_warnings(const HttpSettings& http, std::vector<std::string>& found) {
    const auto& web = *http.web;
    if (!web.users.empty() && !web.tls && !loopback(http.listen_host))
        found.push_back(fmt::format(
            "the passwords of {}'s basic_auth_users cross the network readable: http.listen "
            "\"{}\" is plain HTTP. Add tls_server_config to {} (docs/http.md), or listen on "
            "127.0.0.1 behind a proxy that speaks HTTPS",
            web.path, host_port(http.listen_host, http.listen_port), web.path));
    std::map<int, std::vector<std::string>> users_of_cost;
    for (const auto& [user, hash] : web.users)
        users_of_cost[bcrypt_cost(hash)].push_back(user);
    if (users_of_cost.size() > 1) {
        std::vector<std::string> costs;
        costs.reserve(users_of_cost.size());
        for (const auto& [cost, users] : users_of_cost)
            costs.push_back(fmt::format("{} ({})", cost, fmt::join(users, ", ")));
        found.push_back(fmt::format(
            "the bcrypt hashes of {} have different costs: {}. An unknown user is refused at one "
            "cost, so how long a refusal takes tells which names exist: make every hash with the "
            "same cost (htpasswd -nBC 10 USER)",
            web.path, fmt::join(costs, ", ")));
    }
    constexpr int max_quick_cost = 12;
    for (const auto& [cost, users] : users_of_cost)
        if (cost > max_quick_cost)
            found.push_back(fmt::format(
                "the bcrypt hash of {} in {} has cost {}: each check of its password is {} times "
                "the work of cost 10 (cost 12 took 0.22 s on a 2-core x86 box), and every other "
                "sign-in waits behind it on the one hashing thread; make it with cost 10 to 12",
                fmt::join(users, ", "), web.path, cost, 1 << (cost - 10)));
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
    if (config.http && config.http->web) web_warnings(*config.http, found);
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

bool BrokerAddress::ip_literal() const {
    boost::system::error_code ec;
    ip::make_address(host, ec);
    return !ec;
}

std::string_view to_string(MqttProtocol protocol) {
    switch (protocol) {
        case MqttProtocol::automatic:
            return "auto";
        case MqttProtocol::v5:
            return "5";
        case MqttProtocol::v311:
            return "3.1.1";
    }
    return "auto";
}

std::string host_port(std::string_view host, unsigned port) {
    return host.find(':') != std::string_view::npos ? fmt::format("[{}]:{}", host, port)
                                                    : fmt::format("{}:{}", host, port);
}

bool same_tags(const LinkConfig& a, const LinkConfig& b) {
    return std::ranges::equal(a.modules, b.modules, {}, &ModuleConfig::tags, &ModuleConfig::tags);
}

}  // namespace ioport::config
