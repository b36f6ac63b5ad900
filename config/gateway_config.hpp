// The gateway's configuration (../shared/spec/gateway.md §1 and §4): what the YAML file says,
// validated into plain values. Loading reports every error it finds, each with file, line and
// key, so an operator fixes the file in one pass.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <spdlog/common.h>
#include <boost/asio/ip/address.hpp>
#include <boost/asio/ip/network_v6.hpp>

#include "protocol/device_identification.hpp"
#include "protocol/expected.hpp"
#include "protocol/gateway_map.hpp"
#include "protocol/ioport.hpp"
#include "protocol/modbus_security.hpp"

namespace ioport::config {

using namespace std::chrono_literals;

using gateway::Stale;
using gateway::WordOrder;
enum class Protocol { ioport, id2 };
// As the configuration spells it: "ioport", "id2".
std::string_view protocol_name(Protocol protocol);
// What happens to the outputs when the daemon stops: left as they are, or set to `initial`.
enum class OnShutdown { keep, initial };
// spdlog's levels and names: trace, debug, info, warn, error, critical, off (and spdlog's
// spellings warning and err).
using LogLevel = spdlog::level::level_enum;

// An IPv4 or IPv6 network, as written in `allow`: "10.0.0.0/8", "::1/128", "127.0.0.1"
// (a bare address is a /32 or /128). IPv4 networks are held as IPv4-mapped IPv6 networks,
// a.b.c.d/n as ::ffff:a.b.c.d/(96 + n), so that IPv4 clients of an IPv6 socket match them.
struct Network {
    boost::asio::ip::network_v6 network;  // canonical: no host bits set
    std::string text;                     // as written, for logs
    friend bool operator==(const Network&, const Network&) = default;
};

// Modbus/TCP Security (gateway.md §5.6): TLS with mutual authentication, roles from the client
// certificate.
struct TlsSettings {
    std::string listen_host = "0.0.0.0";  // as ModbusSettings::listen_host
    std::uint16_t listen_port = 802;
    std::string certificate;  // paths, for messages
    std::string key;
    std::string client_ca;
    std::string client_crl;  // "" = none
    // Their contents, read and checked at load (and at each reload, so a renewed certificate is
    // taken by a SIGHUP): PEM.
    std::string certificate_pem;
    std::string key_pem;
    std::string client_ca_pem;
    std::string client_crl_pem;
    // Connections still in their handshake, at most, and at most per_address_handshakes of one
    // client address: they never take max_connections places.
    int max_handshakes = 16;
    std::string default_role;  // "" = none
    modbus_security::Roles roles;
    friend bool operator==(const TlsSettings&, const TlsSettings&) = default;
};

// Of one client address, at most this many connections in their TLS handshake (gateway.md §5.6).
inline constexpr int per_address_handshakes = 4;

struct ModbusSettings {
    // An IPv4 or IPv6 literal, without brackets; "" (`listen: ""`, or no `listen` beside `tls`):
    // no plain Modbus TCP listener.
    std::string listen_host = "0.0.0.0";
    std::uint16_t listen_port = 502;
    bool listen_given = false;                      // `listen` is in the file
    int max_connections = 32;                       // 1..
    std::chrono::microseconds idle_timeout = 5min;  // 0 = never
    std::vector<Network> allow;                     // empty: anyone
    bool read_only = false;
    WordOrder word_order = WordOrder::big;
    Stale stale = Stale::exception;
    std::chrono::microseconds keepalive = 60s;  // TCP keepalive idle time; 0 = off
    // No request from any client for this long puts every output in its safe state; 0 = off.
    std::chrono::microseconds comm_loss_timeout{0};
    std::optional<TlsSettings> tls;  // no `tls:` section, or no `listen`: none
    bool plain() const { return !listen_host.empty(); }
    friend bool operator==(const ModbusSettings&, const ModbusSettings&) = default;
};

// http.web_config_file (gateway.md §7.1): the Prometheus exporter-toolkit's web configuration,
// read and checked at load (and at each reload) like the other files that grant rights.
// client_auth_type, in Go's crypto/tls words: whether a client certificate is asked for, needed,
// and checked against client_ca_file. Only a checked one names a user.
enum class ClientAuth {
    none,                // NoClientCert
    request,             // RequestClientCert: asked for, never checked
    require_any,         // RequireAnyClientCert: needed, never checked
    verify_if_given,     // VerifyClientCertIfGiven
    require_and_verify,  // RequireAndVerifyClientCert
};
enum class TlsVersion { tls12, tls13 };
struct WebTlsSettings {
    std::string cert_file;  // paths, for messages
    std::string key_file;
    std::string client_ca_file;  // "" = none
    std::string cert_pem;        // their contents, PEM
    std::string key_pem;
    std::string client_ca_pem;
    ClientAuth client_auth = ClientAuth::none;
    TlsVersion min_version = TlsVersion::tls12;
    TlsVersion max_version = TlsVersion::tls13;
    friend bool operator==(const WebTlsSettings&, const WebTlsSettings&) = default;
};
struct WebConfig {
    std::string path;
    std::optional<WebTlsSettings> tls;  // none: plain HTTP
    // http_server_config.headers: added to every response after ioportd's own.
    std::vector<std::pair<std::string, std::string>> headers;
    std::map<std::string, std::string> users;  // basic_auth_users: name -> bcrypt hash
    friend bool operator==(const WebConfig&, const WebConfig&) = default;
};

inline constexpr int default_ipv6_prefix = 64;

// The HTTP side (gateway.md §5.4, §7.1): metrics, status page, health; writes by operators.
struct HttpSettings {
    std::string listen_host = "127.0.0.1";  // as ModbusSettings::listen_host
    std::uint16_t listen_port = 8502;
    std::vector<Network> allow;  // empty: anyone
    // Names a request's Host may give besides IP literals, localhost and the machine's host
    // name: a reverse proxy's public name, a DNS alias (gateway.md §5.4).
    std::vector<std::string> server_names;
    std::optional<WebConfig> web;        // http.web_config_file; none: plain, anyone reads (§5.4)
    std::vector<std::string> operators;  // users who may write (§7.1)
    // How many leading bits of an IPv6 client's address make one address for the per-address
    // limits (gateway.md §7.5).
    int ipv6_prefix = default_ipv6_prefix;
    friend bool operator==(const HttpSettings&, const HttpSettings&) = default;
};

// An MQTT broker, as mqtt://host[:port] or mqtts://host[:port] name it.
struct BrokerAddress {
    bool tls = false;  // mqtts://
    std::string host;  // an IP literal (IPv6 without brackets) or a host name
    std::uint16_t port = 1883;
    // An IP address, not a name: nothing to resolve, and TLS checks it as an address.
    bool ip_literal() const;
    friend bool operator==(const BrokerAddress&, const BrokerAddress&) = default;
};
// "mqtts://host:port", "mqtt://[::1]:1883": as the configuration could have written it.
std::string to_string(const BrokerAddress& broker);

// Sparkplug store-and-forward (gateway.md §6.2).
struct StoreSettings {
    std::string path;                                  // a directory of its own
    std::uint64_t max_size = std::uint64_t{64} << 20;  // the oldest records go beyond it
    int forward_rate = 200;  // historical DDATA messages a second, at most
    friend bool operator==(const StoreSettings&, const StoreSettings&) = default;
};
inline constexpr std::uint64_t min_store_size = std::uint64_t{1} << 20;
// A full store of this size is scanned in 2.2 s on the two cores of bench/README.md, about 9 s on
// a box four times slower: within the 13 s of records the disk's queue holds meanwhile at the
// busiest bus measured (docs/store.md); forwarding starts only after the scan.
inline constexpr std::uint64_t max_store_size = std::uint64_t{1} << 30;
inline constexpr std::size_t max_brokers = 16;

// The Sparkplug B edge node (gateway.md §5.5, §6.2).
// Which MQTT the connection speaks (gateway.md §6.2, `protocol:`): 5, falling back to 3.1.1 for a
// broker that refuses 5 or closes the connection without a CONNACK; or one of them only.
enum class MqttProtocol { automatic, v5, v311 };
std::string_view to_string(MqttProtocol protocol);  // "auto", "5", "3.1.1"

struct MqttSettings {
    std::vector<BrokerAddress> brokers;  // tried in order; at least one
    std::string group_id;
    std::string edge_node_id;
    std::string client_id;  // default: ioportd-<group_id>-<edge_node_id>
    std::string username;
    std::string password_file;
    std::string password;  // read from password_file at load (and at each reload)
    std::string ca_file;   // mqtts: the CA that signed the broker's certificate
    std::chrono::microseconds keepalive = 30s;
    MqttProtocol protocol = MqttProtocol::automatic;
    std::string primary_host_id;
    double deadband = 0;                 // analog channels, in engineering units
    std::optional<StoreSettings> store;  // none: what changes while no session can publish is lost
    bool templates = false;              // gateway.md §7.2: one Sparkplug template per module type
    char device_id_separator = '.';      // in device ids: one of sparkplug::device_id_separators
    friend bool operator==(const MqttSettings&, const MqttSettings&) = default;
};

// Plain MQTT with JSON and Home Assistant discovery (gateway.md §6.3). Its own connection, which
// may run beside the Sparkplug node's.
struct MqttJsonSettings {
    // brokers, client_id, username, password, ca_file and keepalive as in mqtt:; the Sparkplug
    // keys stay empty.
    MqttSettings connection;
    std::string topic_prefix = "ioportd";
    bool discovery = true;
    std::string discovery_prefix = "homeassistant";
    double deadband = 0;  // analog channels, in engineering units
    friend bool operator==(const MqttJsonSettings&, const MqttJsonSettings&) = default;
};

struct ModuleConfig {
    ModuleAddress address;
    std::chrono::microseconds poll{0};       // input modules: at most this often; 0 = every cycle
    std::uint16_t initial = 0;               // output modules: the register value sent at start-up
    std::uint16_t safe = 0;                  // output modules: after comm loss; `initial` if unset
    std::chrono::microseconds refresh = 1s;  // output modules: re-send the desired state
    int line = 0;                            // in the file, for messages
    gateway::ModuleTags tags{};              // names, units, scales (§6.1), defaults resolved
    // Equal as settings: where in the file does not matter, and tags are not settings (a reload
    // applies them to a running link without reopening its port or resetting its outputs).
    friend bool operator==(const ModuleConfig& a, const ModuleConfig& b) {
        return a.address == b.address && a.poll == b.poll && a.initial == b.initial &&
               a.safe == b.safe && a.refresh == b.refresh;
    }
};

struct LinkConfig {
    std::string name;
    Protocol protocol = Protocol::ioport;
    std::string device;
    int baud = 115200;
    int unit_id = 1;
    std::chrono::microseconds timeout = 100ms;
    int retries = 1;
    // Client writes that may wait for the line at once, every write path together (§4).
    int max_pending_writes = 64;
    std::vector<ModuleConfig> modules;  // ioport only, in file order
    // Read Device Identification objects by id as `identity:` sets them; "" = ioportd's own
    // (daemon/modbus/device_identity.hpp). MajorMinorRevision is always the version.
    modbus::DeviceIdentity identity{};
    int line = 0;
    friend bool operator==(const LinkConfig& a, const LinkConfig& b) {
        return a.name == b.name && a.protocol == b.protocol && a.device == b.device &&
               a.baud == b.baud && a.unit_id == b.unit_id && a.timeout == b.timeout &&
               a.retries == b.retries && a.max_pending_writes == b.max_pending_writes &&
               a.modules == b.modules && a.identity == b.identity;
    }
};

// Whether two links that are equal as settings also name, unit and scale every module alike.
bool same_tags(const LinkConfig& a, const LinkConfig& b);

struct GatewayConfig {
    std::string file;  // as given, for messages
    ModbusSettings modbus;
    // No `http:` section, or `listen: ""`: no HTTP server (an upgrade never opens a port).
    std::optional<HttpSettings> http;
    // No `mqtt:` section, or no `broker`: no Sparkplug edge node.
    std::optional<MqttSettings> mqtt;
    // No `mqtt_json:` section, or no `broker`: no plain MQTT output.
    std::optional<MqttJsonSettings> mqtt_json;
    std::vector<LinkConfig> links;
    OnShutdown on_shutdown = OnShutdown::keep;
    LogLevel log_level = LogLevel::info;
};

// spdlog's name of the level: "info", "warning".
std::string_view to_string(LogLevel level);
// nullopt for a name spdlog does not know.
std::optional<LogLevel> log_level_from_name(std::string_view name);

struct ConfigError {
    std::string file;
    int line = 0;     // 1-based; 0 when the whole file is concerned
    std::string key;  // dotted path: "links[1].modules[2].type"
    std::string message;
};
// "ioportd.yaml:12: links[0].baud: 9600 is not allowed for protocol ioport: use 38400 or 115200"
std::string to_string(const ConfigError& error);

using ConfigResult = Expected<GatewayConfig, std::vector<ConfigError>>;

// Resolves a device path to the file it names (symlinks followed), so that two spellings of one
// port are found out as duplicates. The default uses std::filesystem::weakly_canonical.
using DeviceResolver = std::function<std::string(const std::string&)>;
std::string resolve_device(const std::string& device);

// Parses and validates YAML text; `file` is used in messages only.
ConfigResult parse_config(std::string_view yaml, const std::string& file,
                          const DeviceResolver& resolve = resolve_device);
// What the configuration allows that weakens it, for the log at start-up and reload and for the
// status page: plain Modbus beside Modbus/TCP Security, a password sent over plain MQTT.
std::vector<std::string> warnings(const GatewayConfig& config);

// Reads the file and parses it; a missing or unreadable file, or one that its group or others
// may write, is one error.
ConfigResult load_config(const std::filesystem::path& path,
                         const DeviceResolver& resolve = resolve_device);

// Whether a client at `address` lies in `network`. IPv4 clients, also as IPv4-mapped IPv6
// addresses (::ffff:a.b.c.d), match IPv4 networks.
bool contains(const Network& network, const boost::asio::ip::address& address);
// "10.0.0.5:502", "[::1]:502": an IPv6 address in brackets, as a listen key or a URL takes it.
std::string host_port(std::string_view host, unsigned port);

}  // namespace ioport::config
