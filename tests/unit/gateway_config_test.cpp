#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "config/check_text.hpp"
#include "config/gateway_config.hpp"
#include "tests/support/beside_program.hpp"
#include "tests/unit/tls_fixtures.hpp"

namespace ioport::config {
namespace {

using namespace std::chrono_literals;
using std::chrono::microseconds;

// Tests must not depend on what /dev holds on the machine that runs them.
std::string identity(const std::string& device) {
    return device;
}

ConfigResult parse(const std::string& yaml) {
    return parse_config(yaml, "test.yaml", identity);
}

std::string describe(const std::vector<ConfigError>& errors) {
    std::string text;
    for (const auto& error : errors)
        text += "\n  " + to_string(error);
    return text;
}

// The example of gateway.md §1, verbatim.
constexpr const char* spec_example = R"(modbus:
  listen: "0.0.0.0:502"       # host:port; "[::]:502" for IPv6
  max_connections: 32         # further clients are refused, the server stays up
  idle_timeout: 5m            # close a client that sent nothing for this long
  allow: []                   # CIDR list, e.g. ["10.0.0.0/8", "127.0.0.1/32"]; empty = anyone
  read_only: false            # true: every write answers exception 01
  word_order: big             # 32-bit values: big = high word first, little = low word first
  stale: exception            # exception | hold (see 3.3)

links:
  - name: hub0
    protocol: ioport          # ioport (hub8u/hub8r) | id2
    device: /dev/ttyUSB0
    baud: 115200              # ioport: 38400 | 115200; id2: 9600
    unit_id: 1                # 1..247, unique
    timeout: 100ms            # per transaction
    retries: 1                # extra tries before a module counts as offline
    modules:
      - { type: dim16, number: 0 }
      - { type: dom16, number: 0, initial: 0x0000, refresh: 1s }
      - { type: acm3p, number: 0, poll: 200ms }   # poll: 0 (default) = every cycle
      - { type: rgbdm, number: 0, initial: 0 }
      - { type: mux8m, number: 0 }
  - name: press
    protocol: id2
    device: /dev/ttyUSB1
    baud: 9600
    unit_id: 2
)";

TEST(GatewayConfig, ParsesTheExampleOfTheSpec) {
    const auto config = parse(spec_example);
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->file, "test.yaml");
    const ModbusSettings& modbus = config->modbus;
    EXPECT_EQ(modbus.listen_host, "0.0.0.0");
    EXPECT_EQ(modbus.listen_port, 502);
    EXPECT_EQ(modbus.max_connections, 32);
    EXPECT_EQ(modbus.idle_timeout, 5min);
    EXPECT_TRUE(modbus.allow.empty());
    EXPECT_FALSE(modbus.read_only);
    EXPECT_EQ(modbus.word_order, WordOrder::big);
    EXPECT_EQ(modbus.stale, Stale::exception);

    ASSERT_EQ(config->links.size(), 2u);
    const LinkConfig& hub = config->links[0];
    EXPECT_EQ(hub.name, "hub0");
    EXPECT_EQ(hub.protocol, Protocol::ioport);
    EXPECT_EQ(hub.device, "/dev/ttyUSB0");
    EXPECT_EQ(hub.baud, 115200);
    EXPECT_EQ(hub.unit_id, 1);
    EXPECT_EQ(hub.timeout, 100ms);
    EXPECT_EQ(hub.retries, 1);
    EXPECT_EQ(hub.line, 11);
    ASSERT_EQ(hub.modules.size(), 5u);
    const std::vector<ModuleAddress> addresses{{ModuleType::dim16, 0},
                                               {ModuleType::dom16, 0},
                                               {ModuleType::acm3p, 0},
                                               {ModuleType::rgbdm, 0},
                                               {ModuleType::mux8m, 0}};
    for (std::size_t i = 0; i < addresses.size(); ++i) {
        EXPECT_EQ(hub.modules[i].address, addresses[i]) << i;
        EXPECT_EQ(hub.modules[i].line, 19 + static_cast<int>(i)) << i;
    }
    EXPECT_EQ(hub.modules[1].initial, 0);
    EXPECT_EQ(hub.modules[1].refresh, 1s);
    EXPECT_EQ(hub.modules[2].poll, 200ms);
    EXPECT_EQ(hub.modules[0].poll, 0us);

    const LinkConfig& press = config->links[1];
    EXPECT_EQ(press.name, "press");
    EXPECT_EQ(press.protocol, Protocol::id2);
    EXPECT_EQ(press.device, "/dev/ttyUSB1");
    EXPECT_EQ(press.baud, 9600);
    EXPECT_EQ(press.unit_id, 2);
    EXPECT_EQ(press.timeout, 200ms);
    EXPECT_TRUE(press.modules.empty());
    EXPECT_EQ(press.line, 24);
}

TEST(GatewayConfig, KeysLeftOutTakeTheDefaultsOfTheSpec) {
    const auto config = parse(R"(links:
  - name: press
    protocol: id2
    device: /dev/ttyS0
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    modules:
      - type: dom16
        number: 3
      - type: dim16
        number: 7
)");
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->modbus.listen_host, "0.0.0.0");
    EXPECT_EQ(config->modbus.listen_port, 502);
    EXPECT_EQ(config->modbus.max_connections, 32);
    EXPECT_EQ(config->modbus.idle_timeout, 5min);
    EXPECT_EQ(config->modbus.keepalive, 60s);
    EXPECT_EQ(config->on_shutdown, OnShutdown::keep);
    EXPECT_EQ(config->log_level, LogLevel::info);

    const LinkConfig& press = config->links[0];
    EXPECT_EQ(press.baud, 9600);
    EXPECT_EQ(press.unit_id, 1);  // 1 + index
    EXPECT_EQ(press.timeout, 200ms);
    EXPECT_EQ(press.retries, 1);

    const LinkConfig& hub = config->links[1];
    EXPECT_EQ(hub.baud, 115200);
    EXPECT_EQ(hub.unit_id, 2);
    EXPECT_EQ(hub.timeout, 100ms);
    EXPECT_EQ(hub.retries, 1);
    EXPECT_EQ(hub.max_pending_writes, 64);
    ASSERT_EQ(hub.modules.size(), 2u);
    EXPECT_EQ(hub.modules[0].address, (ModuleAddress{ModuleType::dom16, 3}));
    EXPECT_EQ(hub.modules[0].initial, 0);
    EXPECT_EQ(hub.modules[0].refresh, 1s);
    EXPECT_EQ(hub.modules[0].line, 9);
    EXPECT_EQ(hub.modules[1].address, (ModuleAddress{ModuleType::dim16, 7}));
    EXPECT_EQ(hub.modules[1].poll, 0us);
    EXPECT_EQ(hub.modules[1].line, 11);
}

TEST(GatewayConfig, PortZeroLetsTheSystemPick) {
    const auto config = parse(R"(modbus: { listen: "127.0.0.1:0" }
links: [{ name: a, protocol: id2, device: /dev/ttyS0 }]
)");
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->modbus.listen_port, 0);
}

TEST(GatewayConfig, ReadsEveryModbusSetting) {
    const auto config = parse(R"(modbus: { listen: "[::]:1502", max_connections: 4, idle_timeout: 0,
  allow: ["10.0.0.0/8", 192.168.1.7, "fd00::/8", "::1"], read_only: true, word_order: little,
  stale: hold }
links: [{ name: a, protocol: id2, device: /dev/ttyS0, unit_id: 247, timeout: 1ms, retries: 0,
          max_pending_writes: 1 }]
)");
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->links[0].max_pending_writes, 1);
    const ModbusSettings& modbus = config->modbus;
    EXPECT_EQ(modbus.listen_host, "::");
    EXPECT_EQ(modbus.listen_port, 1502);
    EXPECT_EQ(modbus.max_connections, 4);
    EXPECT_EQ(modbus.idle_timeout, 0us);
    EXPECT_TRUE(modbus.read_only);
    EXPECT_EQ(modbus.word_order, WordOrder::little);
    EXPECT_EQ(modbus.stale, Stale::hold);
    ASSERT_EQ(modbus.allow.size(), 4u);
    // IPv4 networks as IPv4-mapped IPv6 ones.
    using boost::asio::ip::make_network_v6;
    EXPECT_EQ(modbus.allow[0], (Network{make_network_v6("::ffff:10.0.0.0/104"), "10.0.0.0/8"}));
    EXPECT_EQ(modbus.allow[1], (Network{make_network_v6("::ffff:192.168.1.7/128"), "192.168.1.7"}));
    EXPECT_EQ(modbus.allow[2], (Network{make_network_v6("fd00::/8"), "fd00::/8"}));
    EXPECT_EQ(modbus.allow[3], (Network{make_network_v6("::1/128"), "::1"}));
    EXPECT_EQ(config->links[0].unit_id, 247);
    EXPECT_EQ(config->links[0].timeout, 1ms);
    EXPECT_EQ(config->links[0].retries, 0);
}

TEST(GatewayConfig, ReadsTheServiceSettings) {
    const auto config = parse(R"(modbus: { keepalive: 10s }
on_shutdown: initial
log_level: debug
links: [{ name: a, protocol: id2, device: /dev/ttyS0 }]
)");
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->modbus.keepalive, 10s);
    EXPECT_EQ(config->on_shutdown, OnShutdown::initial);
    EXPECT_EQ(config->log_level, LogLevel::debug);
    const auto off = parse(R"(modbus: { keepalive: 0 }
links: [{ name: a, protocol: id2, device: /dev/ttyS0 }]
)");
    ASSERT_TRUE(off) << describe(off.error());
    EXPECT_EQ(off->modbus.keepalive, 0us);
}

TEST(GatewayConfig, LogLevelsAreSpdlogs) {
    const std::vector<std::pair<std::string, LogLevel>> levels{
        {"trace", LogLevel::trace}, {"debug", LogLevel::debug}, {"info", LogLevel::info},
        {"warn", LogLevel::warn},   {"error", LogLevel::err},   {"critical", LogLevel::critical},
        {"off", LogLevel::off}};
    for (const auto& [name, level] : levels) {
        const auto config =
            parse("log_level: " + name + "\nlinks: [{ name: a, protocol: id2, device: /d }]\n");
        ASSERT_TRUE(config) << name << describe(config.error());
        EXPECT_EQ(config->log_level, level) << name;
        EXPECT_EQ(log_level_from_name(to_string(level)), level) << name;
    }
    EXPECT_EQ(to_string(LogLevel::info), "info");
    // spdlog's from_str() answers off for any name it does not know.
    for (const auto* name : {"", "loud", "Off", "OFF", "INFO", "information"})
        EXPECT_EQ(log_level_from_name(name), std::nullopt) << name;
}

TEST(GatewayConfig, ListenTakesIpLiteralsAndLocalhost) {
    const auto listen = [](const std::string& text) {
        const auto config = parse("modbus: { listen: \"" + text +
                                  "\" }\nlinks: [{ name: a, protocol: id2, device: /d }]\n");
        EXPECT_TRUE(config) << text << (config ? "" : describe(config.error()));
        return config
                   ? config->modbus.listen_host + " " + std::to_string(config->modbus.listen_port)
                   : "";
    };
    EXPECT_EQ(listen("127.0.0.1:1502"), "127.0.0.1 1502");
    EXPECT_EQ(listen("localhost:502"), "127.0.0.1 502");
    EXPECT_EQ(listen("[::1]:65535"), "::1 65535");
}

TEST(GatewayConfig, OutputModulesTakeInitialAsTheRegisterValue) {
    const auto config = parse(R"(links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    baud: 38400
    modules:
      - { type: dom16, number: 1, initial: 0b1010, refresh: 10ms }
      - { type: dom16, number: 2, initial: 65535 }
      - { type: rgbdm, number: 1, initial: magenta }
      - { type: rgbdm, number: 2, initial: 7 }
      - { type: mux8m, number: 1, initial: 0x0102 }
      - { type: mux8m, number: 2, initial: 0x0707 }
)");
    ASSERT_TRUE(config) << describe(config.error());
    const auto& modules = config->links[0].modules;
    ASSERT_EQ(modules.size(), 6u);
    EXPECT_EQ(config->links[0].baud, 38400);
    EXPECT_EQ(modules[0].initial, 0b1010);
    EXPECT_EQ(modules[0].refresh, 10ms);
    EXPECT_EQ(modules[1].initial, 0xFFFF);
    EXPECT_EQ(modules[2].initial, static_cast<std::uint16_t>(Colour::magenta));
    EXPECT_EQ(modules[3].initial, 7);
    EXPECT_EQ(modules[4].initial, 0x0102);
    EXPECT_EQ(modules[5].initial, 0x0707);
}

// --check-config prints an output module's values as the file writes them: an rgbdm's by colour.
TEST(GatewayConfig, CheckConfigShowsOutputValuesAsTheFileWritesThem) {
    const auto config = parse(R"(links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    modules:
      - { type: dom16, number: 0, initial: 0b1010 }
      - { type: rgbdm, number: 0, initial: off }
      - { type: rgbdm, number: 1, initial: 7, safe: red }
      - { type: mux8m, number: 0, initial: 0x0102 }
)");
    ASSERT_TRUE(config) << describe(config.error());
    const auto text = check_config_text(*config);
    for (const auto* expected : {"  dom16 0  initial 0x000A, safe 0x000A, refresh 1s\n",
                                 "  rgbdm 0  initial off, safe off, refresh 1s\n",
                                 "  rgbdm 1  initial white, safe red, refresh 1s\n",
                                 "  mux8m 0  initial 0x0102, safe 0x0102, refresh 1s\n"})
        EXPECT_NE(text.find(expected), std::string::npos) << "missing '" << expected << "' in:\n"
                                                          << text;
}

// §7.2: mqtt.templates, parsed as a boolean and shown by --check-config on the edge node's line.
TEST(GatewayConfig, SparkplugTemplatesAreParsedAndShown) {
    const std::string section = R"(mqtt:
  broker: "mqtt://127.0.0.1:1883"
  group_id: plant1
  edge_node_id: box7
)";
    const std::string links = R"(links:
  - { name: hub0, protocol: ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }
)";
    const auto on = parse(section + "  templates: true\n" + links);
    ASSERT_TRUE(on) << describe(on.error());
    EXPECT_TRUE(on->mqtt->templates);
    EXPECT_NE(check_config_text(*on).find("Sparkplug B edge node plant1/box7 on "
                                          "mqtt://127.0.0.1:1883 (MQTT 5, or 3.1.1 if the broker "
                                          "refuses 5), templates (one per module type)\n"),
              std::string::npos)
        << check_config_text(*on);
    const auto off = parse(section + "  templates: false\n" + links);
    ASSERT_TRUE(off) << describe(off.error());
    EXPECT_FALSE(off->mqtt->templates);
    EXPECT_NE(check_config_text(*off).find(
                  "Sparkplug B edge node plant1/box7 on mqtt://127.0.0.1:1883 (MQTT 5, or 3.1.1 "
                  "if the broker refuses 5)\n"),
              std::string::npos)
        << check_config_text(*off);
    EXPECT_NE(*on->mqtt, *off->mqtt);  // a reload that turns them on or off is a new session
}

// §6.2 `protocol`: auto by default, "5" or "3.1.1" quoted or not, both outputs; shown.
TEST(GatewayConfig, MqttProtocolIsAutoFiveOr311) {
    const std::string links = R"(links:
  - { name: hub0, protocol: ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }
)";
    const auto with = [&](const std::string& line) {
        return parse(
            "mqtt:\n  broker: \"mqtt://127.0.0.1:1883\"\n  group_id: plant1\n"
            "  edge_node_id: box7\n" +
            line +
            "mqtt_json:\n  broker: "
            "\"mqtt://127.0.0.1:1883\"\n" +
            line + links);
    };
    const auto automatic = with("");
    ASSERT_TRUE(automatic) << describe(automatic.error());
    EXPECT_EQ(automatic->mqtt->protocol, MqttProtocol::automatic);
    EXPECT_EQ(automatic->mqtt_json->connection.protocol, MqttProtocol::automatic);
    const auto v311 = with("  protocol: 3.1.1\n");
    ASSERT_TRUE(v311) << describe(v311.error());
    EXPECT_EQ(v311->mqtt->protocol, MqttProtocol::v311);
    EXPECT_EQ(v311->mqtt_json->connection.protocol, MqttProtocol::v311);
    EXPECT_NE(check_config_text(*v311).find("on mqtt://127.0.0.1:1883 (MQTT 3.1.1 only)"),
              std::string::npos)
        << check_config_text(*v311);
    const auto v5 = with("  protocol: \"5\"\n");
    ASSERT_TRUE(v5) << describe(v5.error());
    EXPECT_EQ(v5->mqtt->protocol, MqttProtocol::v5);
    EXPECT_EQ(v5->mqtt_json->connection.protocol, MqttProtocol::v5);
    const auto wrong = with("  protocol: 3\n");
    ASSERT_FALSE(wrong);
    EXPECT_NE(describe(wrong.error()).find("'3' is not an MQTT version: use auto"),
              std::string::npos)
        << describe(wrong.error());
}

// issue 49: device_id_separator, "." by default; one of . - _ :, shown when not the default.
TEST(GatewayConfig, DeviceIdSeparatorIsOneOfFour) {
    const auto with = [](const std::string& line) {
        return parse(
            "mqtt:\n  broker: \"mqtt://127.0.0.1:1883\"\n  group_id: plant1\n"
            "  edge_node_id: box7\n" +
            line +
            "links:\n  - { name: hub0, protocol: "
            "ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }\n");
    };
    const auto dot = with("");
    ASSERT_TRUE(dot) << describe(dot.error());
    EXPECT_EQ(dot->mqtt->device_id_separator, '.');
    EXPECT_EQ(check_config_text(*dot).find("device ids"), std::string::npos);
    const auto underscore = with("  device_id_separator: _\n");
    ASSERT_TRUE(underscore) << describe(underscore.error());
    EXPECT_EQ(underscore->mqtt->device_id_separator, '_');
    EXPECT_NE(check_config_text(*underscore).find("Sparkplug device ids with '_': hub0_dim16_0\n"),
              std::string::npos)
        << check_config_text(*underscore);
    for (const char* wrong : {"\"/\"", "\"ab\"", "\"\"", "x"}) {
        const auto refused = with(std::string("  device_id_separator: ") + wrong + "\n");
        ASSERT_FALSE(refused) << wrong;
        EXPECT_NE(describe(refused.error()).find("is not a separator of device ids: use \".\""),
                  std::string::npos)
            << describe(refused.error());
    }
}

// §5.3: `safe` takes what `initial` takes and defaults to it; comm_loss_timeout defaults to off.
// §5.2: `identity` objects per link.
TEST(GatewayConfig, SafeValuesCommLossAndIdentity) {
    const auto config = parse(R"(modbus:
  comm_loss_timeout: 10s
links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    identity: { vendor_name: ACME Automation, model_name: hub8u, user_application_name: Press 2 }
    modules:
      - { type: dom16, number: 1, initial: 0x00FF, safe: 0 }
      - { type: dom16, number: 2, initial: 0x00FF }
      - { type: rgbdm, number: 1, initial: green, safe: red }
      - { type: mux8m, number: 1, safe: 0x0707 }
)");
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->modbus.comm_loss_timeout, 10s);
    const auto& modules = config->links[0].modules;
    EXPECT_EQ(modules[0].safe, 0);
    EXPECT_EQ(modules[1].safe, 0x00FF);  // the default: initial
    EXPECT_EQ(modules[2].safe, static_cast<std::uint16_t>(Colour::red));
    EXPECT_EQ(modules[3].safe, 0x0707);
    const auto& identity = config->links[0].identity;
    EXPECT_EQ(identity[0], "ACME Automation");
    EXPECT_EQ(identity[1], "");  // ioportd's own, filled in by the daemon
    EXPECT_EQ(identity[5], "hub8u");
    EXPECT_EQ(identity[6], "Press 2");
    const auto defaults = parse(spec_example);
    ASSERT_TRUE(defaults) << describe(defaults.error());
    EXPECT_EQ(defaults->modbus.comm_loss_timeout, 0s);
}

// §5.4: no section, no HTTP server (an upgrade never opens a port); the section alone takes the
// defaults; listen "" turns it off.
TEST(GatewayConfig, TheHttpSection) {
    const std::string links = R"(links:
  - { name: hub0, protocol: ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }
)";
    const auto absent = parse(links);
    ASSERT_TRUE(absent) << describe(absent.error());
    EXPECT_FALSE(absent->http);
    const auto defaults = parse("http:\n" + links);
    ASSERT_TRUE(defaults) << describe(defaults.error());
    ASSERT_TRUE(defaults->http);
    EXPECT_EQ(defaults->http->listen_host, "127.0.0.1");
    EXPECT_EQ(defaults->http->listen_port, 8502);
    EXPECT_TRUE(defaults->http->allow.empty());
    EXPECT_TRUE(defaults->http->server_names.empty());
    const auto set = parse(
        "http:\n  listen: \"[::]:9100\"\n  allow: [10.0.0.0/8]\n"
        "  server_names: [gateway.plant.example, GW-7, scada_alias]\n" +
        links);
    ASSERT_TRUE(set) << describe(set.error());
    ASSERT_TRUE(set->http);
    EXPECT_EQ(set->http->listen_host, "::");
    EXPECT_EQ(set->http->listen_port, 9100);
    ASSERT_EQ(set->http->allow.size(), 1u);
    EXPECT_EQ(set->http->allow[0].text, "10.0.0.0/8");
    EXPECT_EQ(set->http->server_names,
              (std::vector<std::string>{"gateway.plant.example", "GW-7", "scada_alias"}));
    const auto off = parse("http:\n  listen: \"\"\n" + links);
    ASSERT_TRUE(off) << describe(off.error());
    EXPECT_FALSE(off->http);
}

// A file of the test's that removes itself; `mode` as chmod takes it.
class TempFile {
  public:
    TempFile(const std::string& content, std::filesystem::perms mode)
        : path_(std::filesystem::temp_directory_path() /
                ("ioportd-config-test-" + std::to_string(::getpid()) + "-" +
                 std::to_string(counter_++))) {
        std::ofstream(path_) << content;
        std::filesystem::permissions(path_, mode);
    }
    ~TempFile() { std::filesystem::remove(path_); }
    TempFile(const TempFile&) = delete;
    TempFile& operator=(const TempFile&) = delete;
    std::string path() const { return path_.string(); }

  private:
    static inline int counter_ = 0;
    std::filesystem::path path_;
};

using std::filesystem::perms;
constexpr auto owner_only = perms::owner_read | perms::owner_write;

// §5.5: the Sparkplug edge node's settings; no broker, no edge node.
TEST(GatewayConfig, TheMqttSection) {
    const std::string links = R"(links:
  - { name: hub0, protocol: ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }
)";
    const TempFile password("s3cret\n", owner_only | perms::group_read);
    const auto full = parse(
        "mqtt:\n  broker: \"mqtts://broker.plant.example\"\n"
        "  group_id: plant1\n  edge_node_id: box7\n  username: box7\n"
        "  password_file: " +
        password.path() +
        "\n"
        "  ca_file: /dev/null\n  keepalive: 10s\n  primary_host_id: scada\n"
        "  deadband: 0.25\n" +
        links);
    ASSERT_TRUE(full) << describe(full.error());
    ASSERT_TRUE(full->mqtt);
    const auto& m = *full->mqtt;
    EXPECT_EQ(m.brokers,
              (std::vector<config::BrokerAddress>{{true, "broker.plant.example", 8883}}));
    EXPECT_FALSE(m.store);
    EXPECT_EQ(m.group_id, "plant1");
    EXPECT_EQ(m.edge_node_id, "box7");
    EXPECT_EQ(m.client_id, "ioportd-plant1-box7");
    EXPECT_EQ(m.password, "s3cret");
    EXPECT_EQ(m.keepalive, 10s);
    EXPECT_EQ(m.primary_host_id, "scada");
    EXPECT_DOUBLE_EQ(m.deadband, 0.25);
    const auto plain = parse(
        "mqtt:\n  broker: \"mqtt://[::1]\"\n  group_id: g\n"
        "  edge_node_id: n\n  client_id: gw-7\n" +
        links);
    ASSERT_TRUE(plain) << describe(plain.error());
    EXPECT_EQ(plain->mqtt->brokers, (std::vector<config::BrokerAddress>{{false, "::1", 1883}}));
    EXPECT_EQ(config::to_string(plain->mqtt->brokers[0]), "mqtt://[::1]:1883");
    EXPECT_EQ(plain->mqtt->client_id, "gw-7");
    EXPECT_EQ(plain->mqtt->keepalive, 30s);
    EXPECT_EQ(plain->mqtt->deadband, 0.0);
    EXPECT_FALSE(m.templates);  // gateway.md §7.2: off by default
    EXPECT_FALSE(plain->mqtt->templates);
    const auto off = parse("mqtt:\n  group_id: g\n" + links);
    ASSERT_TRUE(off) << describe(off.error());
    EXPECT_FALSE(off->mqtt);
    EXPECT_FALSE(parse(links)->mqtt);
}

// §6.3, the example verbatim: plain MQTT beside (or instead of) Sparkplug, its own connection.
TEST(GatewayConfig, TheMqttJsonSection) {
    const std::string links = R"(links:
  - { name: hub0, protocol: ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }
)";
    const auto spec = parse(
        R"(mqtt_json:                                # absent = off; may run beside mqtt: (Sparkplug)
  broker: "mqtt://127.0.0.1:1883"         # client_id, username, password_file, ca_file,
  topic_prefix: "ioportd/box7"            #   keepalive as in mqtt:
  discovery: true                         # Home Assistant MQTT discovery
  discovery_prefix: "homeassistant"
  deadband: 0.0
)" + links);
    ASSERT_TRUE(spec) << describe(spec.error());
    ASSERT_TRUE(spec->mqtt_json);
    EXPECT_FALSE(spec->mqtt);
    const auto& j = *spec->mqtt_json;
    EXPECT_EQ(j.connection.brokers,
              (std::vector<config::BrokerAddress>{{false, "127.0.0.1", 1883}}));
    EXPECT_EQ(j.connection.client_id, "ioportd-json_ioportd_2Fbox7");
    EXPECT_EQ(j.connection.keepalive, 30s);
    EXPECT_EQ(j.topic_prefix, "ioportd/box7");
    EXPECT_TRUE(j.discovery);
    EXPECT_EQ(j.discovery_prefix, "homeassistant");
    EXPECT_EQ(j.deadband, 0.0);

    const auto both = parse(
        "mqtt:\n  broker: mqtt://b\n  group_id: g\n  edge_node_id: n\n"
        "mqtt_json:\n  brokers: [mqtt://b, mqtt://c]\n  client_id: json-7\n  keepalive: 10s\n"
        "  discovery: false\n  deadband: 0.5\n" +
        links);
    ASSERT_TRUE(both) << describe(both.error());
    ASSERT_TRUE(both->mqtt && both->mqtt_json);
    EXPECT_EQ(both->mqtt->client_id, "ioportd-g-n");
    EXPECT_EQ(both->mqtt_json->connection.client_id, "json-7");
    EXPECT_EQ(both->mqtt_json->connection.brokers.size(), 2U);
    EXPECT_EQ(both->mqtt_json->connection.keepalive, 10s);
    EXPECT_EQ(both->mqtt_json->topic_prefix, "ioportd");  // the default
    EXPECT_FALSE(both->mqtt_json->discovery);
    EXPECT_DOUBLE_EQ(both->mqtt_json->deadband, 0.5);
    EXPECT_TRUE(both->mqtt_json->connection.group_id.empty());

    const auto off = parse("mqtt_json:\n  topic_prefix: x\n" + links);
    ASSERT_TRUE(off) << describe(off.error());
    EXPECT_FALSE(off->mqtt_json);
    EXPECT_FALSE(parse("mqtt_json:\n" + links)->mqtt_json);
}

// A link whose one module, an acm3p, is in block style: keys may be appended at line 8.
const std::string hub_for_tags = R"(links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    modules:
      - type: acm3p
        number: 0
)";

// The example of gateway.md §6.1, verbatim.
constexpr const char* tags_example = R"(links:
  - name: hub0
    modules:
      - type: acm3p
        number: 0
        name: "boiler 1"                        # default: "acm3p 0"
        channels:                               # analog modules, by channel index
          0: { name: "supply temperature", unit: "°C", scale: [0, 100, -20, 150] }
          1: { name: "pressure", unit: "bar", scale: [20, 100, 0, 10], range: [0, 6] }
      - { type: dim16, number: 0, inputs: { 0: "door open", 5: "pump running" } }
      - { type: dom16, number: 0, outputs: { 0: "horn", 1: "lamp" } }
)";

TEST(GatewayConfig, TheTagsOfSection61) {
    // The spec leaves out the link's protocol and device.
    std::string yaml = tags_example;
    yaml.replace(yaml.find("    modules:"), 0, "    protocol: ioport\n    device: /dev/ttyUSB0\n");
    const auto config = parse(yaml);
    ASSERT_TRUE(config) << describe(config.error());
    const auto& modules = config->links[0].modules;
    ASSERT_EQ(modules.size(), 3U);
    const auto& acm3p = modules[0].tags;
    EXPECT_EQ(acm3p.name, "boiler 1");
    ASSERT_EQ(acm3p.channels.size(), 3U);
    EXPECT_EQ(acm3p.channels[0].name, "supply temperature");
    EXPECT_EQ(acm3p.channels[0].unit, "°C");
    EXPECT_EQ(acm3p.channels[0].scale, (gateway::Scale{0, 100, -20, 150}));
    EXPECT_EQ(acm3p.channels[0].range, (std::array<double, 2>{-20, 150}));
    EXPECT_EQ(acm3p.channels[1].unit, "bar");
    EXPECT_EQ(acm3p.channels[1].range, (std::array<double, 2>{0, 6}));
    // Channel 2 is not configured: its unscaled unit and full scale.
    EXPECT_EQ(acm3p.channels[2].name, "");
    EXPECT_EQ(acm3p.channels[2].unit, "%");
    EXPECT_FALSE(acm3p.channels[2].scale);
    EXPECT_EQ(acm3p.channels[2].range, (std::array<double, 2>{0, 100}));
    EXPECT_EQ(modules[1].tags.name, "dim16 0");
    EXPECT_EQ(modules[1].tags.points[0], "door open");
    EXPECT_EQ(modules[1].tags.points[5], "pump running");
    EXPECT_EQ(modules[1].tags.points[1], "");
    EXPECT_EQ(modules[2].tags.points[1], "lamp");
    EXPECT_TRUE(modules[2].tags.channels.empty());
}

TEST(GatewayConfig, AScaleWithoutAUnitHasNoneAndAUnitAloneKeepsTheUnscaledValue) {
    const auto config = parse(R"(links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    modules:
      - { type: dccim, number: 0, channels: { 0: { scale: [4, 20, 0, 100] } } }
      - { type: dcvim, number: 0, channels: { 0: { unit: "", range: [-1, 40] } } }
)");
    ASSERT_TRUE(config) << describe(config.error());
    const auto& dccim = config->links[0].modules[0].tags.channels[0];
    EXPECT_EQ(dccim.unit, "");
    EXPECT_EQ(dccim.range, (std::array<double, 2>{0, 100}));
    const auto& dcvim = config->links[0].modules[1].tags.channels[0];
    EXPECT_EQ(dcvim.unit, "");
    EXPECT_FALSE(dcvim.scale);
    EXPECT_EQ(dcvim.range, (std::array<double, 2>{-1, 40}));
}

TEST(GatewayConfig, TagsAreNotSettings) {
    const auto plain = parse(hub_for_tags);
    const auto named = parse(hub_for_tags + "        name: boiler\n");
    ASSERT_TRUE(plain) << describe(plain.error());
    ASSERT_TRUE(named) << describe(named.error());
    // Equal as settings, so a reload keeps the link; not the same tags, so it retags it.
    EXPECT_EQ(plain->links[0], named->links[0]);
    EXPECT_FALSE(same_tags(plain->links[0], named->links[0]));
    EXPECT_TRUE(same_tags(plain->links[0], plain->links[0]));
}

// --- Errors ---------------------------------------------------------------------------------

// Lines 1-6: a valid ioport link. Cases append a key of link 0 or a module at line 7.
const std::string hub = R"(links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    modules:
      - { type: dim16, number: 0 }
)";
// Lines 7-9 when appended to `hub`: a valid id2 link.
const std::string press = R"(  - name: press
    protocol: id2
    device: /dev/ttyS0
)";
// Puts a modbus section of one key before `hub`: the key is on line 2.
std::string modbus(const std::string& line) {
    return "modbus:\n  " + line + "\n" + hub;
}

struct Case {
    std::string yaml;
    int line;
    std::string key;
    std::string fragment;  // of the message: what is allowed
};

void expect_one_error(const Case& c) {
    SCOPED_TRACE(c.yaml);
    const auto config = parse(c.yaml);
    ASSERT_FALSE(config);
    ASSERT_EQ(config.error().size(), 1u) << describe(config.error());
    const ConfigError& error = config.error()[0];
    EXPECT_EQ(error.file, "test.yaml");
    EXPECT_EQ(error.line, c.line) << to_string(error);
    EXPECT_EQ(error.key, c.key) << to_string(error);
    EXPECT_NE(error.message.find(c.fragment), std::string::npos)
        << to_string(error) << "\n  should contain: " << c.fragment;
}

TEST(GatewayConfigErrors, AYamlSyntaxErrorIsOneErrorWithItsLine) {
    expect_one_error({"links:\n  - { name: hub0,\n    protocol: [ioport\n", 4, "", "YAML syntax"});
    expect_one_error({"links:\n  - name: a\n\tprotocol: id2\n", 3, "", "tab"});
}

// Found by fuzz/config: yaml-cpp 0.7's LoadAll loops on these, keeping an empty document per turn
// until memory runs out (jbeder/yaml-cpp#1040). They are syntax errors at the stray comma.
TEST(GatewayConfigErrors, AStrayCommaIsASyntaxErrorNotALoop) {
    expect_one_error({",#", 1, "", "YAML syntax error at column 1: a ','"});
    expect_one_error({",", 1, "", "YAML syntax error at column 1: a ','"});
    expect_one_error({hub + "...\n  ,\n", 8, "", "YAML syntax error at column 3: a ','"});
    expect_one_error({"- a\n,\n", 2, "", "YAML syntax error"});
    expect_one_error({"&anchor ,", 1, "", "YAML syntax error at column 9: a ','"});
    expect_one_error({"!tag ,", 1, "", "YAML syntax error"});
    expect_one_error({"%YAML 1.2\n,", 2, "", "YAML syntax error"});
}

// Two documents that are empty start at different '---': a second document, not a loop.
TEST(GatewayConfigErrors, EmptyDocumentsAreDocuments) {
    const auto config = parse("---\n---\n");
    ASSERT_FALSE(config);
    ASSERT_EQ(config.error().size(), 2u) << describe(config.error());
    EXPECT_EQ(config.error()[0].line, 0);
    EXPECT_NE(config.error()[0].message.find("empty"), std::string::npos);
    EXPECT_EQ(config.error()[1].line, 3);  // an empty document's root: the end of the text
    EXPECT_NE(config.error()[1].message.find("one YAML document"), std::string::npos);
}

TEST(GatewayConfigErrors, TheFileAsAWhole) {
    expect_one_error({"", 0, "links", "empty"});
    expect_one_error({"# only a comment\n", 0, "links", "empty"});
    expect_one_error({"- a\n- b\n", 1, "", "mapping with the keys modbus and links"});
    expect_one_error({"modbus: {}\n", 1, "links", "at least one link"});
    expect_one_error({"links: []\n", 1, "links", "at least one link, found an empty list"});
    expect_one_error({"links: hub0\n", 1, "links", "at least one link, found a single value"});
    expect_one_error({hub + "---\n" + hub, 8, "", "one YAML document"});
    expect_one_error({"logging: debug\n" + hub, 1, "logging",
                      "allowed here are modbus, http, mqtt, mqtt_json, links"});
}

TEST(GatewayConfigErrors, UnknownAndDuplicateKeys) {
    expect_one_error({modbus("port: 502"), 2, "modbus.port",
                      "unknown key: allowed here are "
                      "listen, max_connections"});
    expect_one_error({hub + "    baudrate: 9600\n", 7, "links[0].baudrate",
                      "allowed here are name, protocol, device, baud, unit_id, timeout, "
                      "retries, modules"});
    expect_one_error({hub + "      - { type: dim16, number: 1, mode: fast }\n", 7,
                      "links[0].modules[1].mode", "allowed here are type, number, poll"});
    expect_one_error({hub + "    name: hub1\n", 7, "links[0].name", "already given at line 2"});
    expect_one_error(
        {"modbus:\n  stale: hold\n  stale: exception\n" + hub, 3, "modbus.stale", "duplicate key"});
}

TEST(GatewayConfigErrors, WrongTypes) {
    expect_one_error({modbus("max_connections: [1]"), 2, "modbus.max_connections",
                      "expected a number 1..65535, found a list"});
    expect_one_error({modbus("max_connections: \"8\""), 2, "modbus.max_connections", "quoted"});
    expect_one_error({modbus("max_connections: eight"), 2, "modbus.max_connections",
                      "not a whole number: use 1..65535"});
    expect_one_error({modbus("read_only: yes"), 2, "modbus.read_only", "use true or false"});
    expect_one_error({modbus("read_only: \"true\""), 2, "modbus.read_only", "use true or false"});
    expect_one_error({modbus("read_only:"), 2, "modbus.read_only", "found no value"});
    expect_one_error({modbus("listen: { host: 0.0.0.0 }"), 2, "modbus.listen",
                      "expected host:port, or \"\" for no plain Modbus TCP, found a mapping"});
    expect_one_error({"modbus: [listen]\n" + hub, 1, "modbus", "expected a mapping"});
    expect_one_error({hub + "    unit_id: \"3\"\n", 7, "links[0].unit_id", "quoted"});
    expect_one_error(
        {hub + "    modules: { type: dim16 }\n", 7, "links[0].modules", "duplicate key"});
    expect_one_error({"links:\n  - hub0\n", 2, "links[0]", "expected a mapping"});
    expect_one_error({"modbus: { [listen]: x }\n" + hub, 1, "modbus", "a key must be a name"});
}

TEST(GatewayConfigErrors, ModbusSettingsOutOfRange) {
    expect_one_error(
        {modbus("listen: \"plc.local:502\""), 2, "modbus.listen", "use an IP address"});
    expect_one_error({modbus("listen: 0.0.0.0"), 2, "modbus.listen", "no port"});
    expect_one_error({modbus("listen: \"[::1]\""), 2, "modbus.listen", "no port"});
    expect_one_error(
        {modbus("listen: 0.0.0.0:65536"), 2, "modbus.listen", "port must be 0..65535"});
    expect_one_error({modbus("listen: 0.0.0.0:0x1f6"), 2, "modbus.listen", "0..65535"});
    expect_one_error({modbus("listen: \"::1:502\""), 2, "modbus.listen", "go in brackets"});
    expect_one_error({modbus("listen: \"[10.0.0.1]:502\""), 2, "modbus.listen", "IPv6"});
    expect_one_error({modbus("listen: 10.0.0:502"), 2, "modbus.listen", "use an IP address"});
    expect_one_error({modbus("listen: \"[fe80::1%eth0]:502\""), 2, "modbus.listen",
                      "not an IPv6 address in brackets"});
    expect_one_error({modbus("max_connections: 0"), 2, "modbus.max_connections",
                      "0 is out of range: use 1..65535"});
    expect_one_error(
        {modbus("max_connections: 65536"), 2, "modbus.max_connections", "use 1..65535"});
    expect_one_error(
        {modbus("max_connections: -1"), 2, "modbus.max_connections", "-1 is out of range"});
    expect_one_error({modbus("idle_timeout: 5"), 2, "modbus.idle_timeout", "e.g. 500us"});
    expect_one_error({modbus("word_order: middle"), 2, "modbus.word_order", "use big or little"});
    expect_one_error({modbus("stale: zero"), 2, "modbus.stale", "use exception or hold"});
    expect_one_error({modbus("keepalive: 121m"), 2, "modbus.keepalive", "out of range"});
    expect_one_error({"on_shutdown: off\n" + hub, 1, "on_shutdown", "use keep or initial"});
    expect_one_error({"log_level: loud\n" + hub, 1, "log_level", "use trace or debug or info"});
    expect_one_error({"log_level: Off\n" + hub, 1, "log_level",
                      "'Off' is not allowed: use trace or debug or info or warn or error or "
                      "critical or off"});
}

TEST(GatewayConfigErrors, AllowListEntries) {
    expect_one_error({modbus("allow: [10.1.0.0/8]"), 2, "modbus.allow[0]",
                      "host bits set: did you mean 10.0.0.0/8?"});
    expect_one_error(
        {modbus("allow: [\"fd00::1/8\"]"), 2, "modbus.allow[0]", "did you mean fd00::/8?"});
    expect_one_error({modbus("allow: [\"127.0.0.1\", 10.0.0.0/33]"), 2, "modbus.allow[1]",
                      "prefix length after / must be 0..32"});
    expect_one_error({modbus("allow: [\"::/129\"]"), 2, "modbus.allow[0]", "must be 0..128"});
    expect_one_error({modbus("allow: [10.0.0.0/]"), 2, "modbus.allow[0]", "0..32"});
    expect_one_error(
        {modbus("allow: [1.0.0.0/0]"), 2, "modbus.allow[0]", "did you mean 0.0.0.0/0?"});
    expect_one_error({modbus("allow: [\"::1/0\"]"), 2, "modbus.allow[0]", "did you mean ::/0?"});
    expect_one_error({modbus("allow: [192.168.1.1/24]"), 2, "modbus.allow[0]",
                      "'192.168.1.1/24' has host bits set: did you mean 192.168.1.0/24?"});
    // Asio's own parser reads the length with atoi, which makes this /8.
    expect_one_error({modbus("allow: [10.0.0.0/4294967304]"), 2, "modbus.allow[0]", "0..32"});
    for (const auto* prefix : {"10.0.0.0/-1", "10.0.0.0/0x8", "10.0.0.0/ 8", "10.0.0.0/8/8"})
        expect_one_error({modbus(std::string("allow: [\"") + prefix + "\"]"), 2, "modbus.allow[0]",
                          "the prefix length after / must be 0..32"});
    expect_one_error({modbus("allow: [plc.local]"), 2, "modbus.allow[0]", "not an IP network"});
    expect_one_error({modbus("allow: [10.0.0/8]"), 2, "modbus.allow[0]", "not an IP network"});
    expect_one_error(
        {modbus("allow: [\"fe80::1%eth0\"]"), 2, "modbus.allow[0]", "not an IP network"});
    expect_one_error({modbus("allow: [\"/8\"]"), 2, "modbus.allow[0]", "not an IP network"});
    expect_one_error({modbus("allow: 10.0.0.0/8"), 2, "modbus.allow", "expected a list"});
    expect_one_error({"modbus:\n  allow:\n    - 10.0.0.0/8\n    - [1]\n" + hub, 4,
                      "modbus.allow[1]", "found a list"});
}

TEST(GatewayConfigErrors, LinkSettings) {
    expect_one_error({hub + "    baud: 9600\n", 7, "links[0].baud",
                      "9600 is not allowed for protocol ioport: use 38400 or 115200"});
    expect_one_error({hub + press + "    baud: 115200\n", 10, "links[1].baud",
                      "115200 is not allowed for protocol id2: use 9600"});
    expect_one_error({hub + "    unit_id: 0\n", 7, "links[0].unit_id", "use 1..247"});
    expect_one_error({hub + "    unit_id: 248\n", 7, "links[0].unit_id", "use 1..247"});
    expect_one_error({hub + "    timeout: 0\n", 7, "links[0].timeout", "use 1ms..10s"});
    expect_one_error({hub + "    timeout: 11s\n", 7, "links[0].timeout", "use 1ms..10s"});
    expect_one_error({hub + "    timeout: 100\n", 7, "links[0].timeout", "e.g. 500us"});
    expect_one_error({hub + "    retries: 11\n", 7, "links[0].retries", "use 0..10"});
    expect_one_error(
        {hub + "    max_pending_writes: 0\n", 7, "links[0].max_pending_writes", "use 1..1024"});
    expect_one_error(
        {hub + "    max_pending_writes: 1025\n", 7, "links[0].max_pending_writes", "use 1..1024"});
    expect_one_error({hub + "    protocol: modbus\n", 7, "links[0].protocol", "duplicate key"});
    expect_one_error({"links:\n  - name: x\n    protocol: modbus\n    device: /d\n", 3,
                      "links[0].protocol", "use ioport or id2"});
    expect_one_error({"links:\n  - name: x\n    device: /d\n", 2, "links[0].protocol",
                      "missing: use protocol: ioport"});
    expect_one_error({"links:\n  - protocol: id2\n    device: /d\n", 2, "links[0].name",
                      "missing: every link needs a name"});
    expect_one_error({"links:\n  - name: \"\"\n    protocol: id2\n    device: /d\n", 2,
                      "links[0].name", "must not be empty"});
    expect_one_error({"links:\n  - name: x\n    protocol: id2\n", 2, "links[0].device",
                      "missing: the serial port"});
    expect_one_error({"links:\n  - name: x\n    protocol: id2\n    device:\n", 4, "links[0].device",
                      "found no value"});
}

TEST(GatewayConfigErrors, ADuplicateIsReportedAtItsSecondOccurrence) {
    expect_one_error({hub + "  - { name: hub0, protocol: id2, device: /dev/ttyS0 }\n", 7,
                      "links[1].name", "'hub0' is already used at line 2"});
    // Sparkplug hosts may not tell metric names apart by case alone.
    expect_one_error({hub + "  - { name: Hub0, protocol: id2, device: /dev/ttyS0 }\n", 7,
                      "links[1].name",
                      "'Hub0' is already used at line 2: names must be unique, "
                      "and unique ignoring case"});
    expect_one_error({hub + "  - { name: b, protocol: id2, device: /dev/ttyUSB0 }\n", 7,
                      "links[1].device", "already used by link 'hub0' (line 2)"});
    expect_one_error({hub + press + "    unit_id: 1\n", 10, "links[1].unit_id",
                      "unit id 1 is already used by link 'hub0' (line 2)"});
    // Link 1 takes unit id 2 by default, which link 2 already has: reported at link 1.
    expect_one_error(
        {"links:\n"
         "  - { name: a, protocol: id2, device: /a, unit_id: 2 }\n"
         "  - { name: b, protocol: id2, device: /b }\n",
         3, "links[1].unit_id", "(the default: 1 + the link's index)"});
    expect_one_error({hub + "      - { type: dim16, number: 0 }\n", 7, "links[0].modules[1]",
                      "dim16 0 is already configured on this link at line 6"});
}

TEST(GatewayConfigErrors, TheDefaultUnitIdMustBeAValidOne) {
    std::string yaml = "links:\n";
    for (int i = 0; i < 248; ++i)
        yaml += "  - { name: l" + std::to_string(i) + ", protocol: id2, device: /d" +
                std::to_string(i) + " }\n";
    expect_one_error({yaml, 249, "links[247].unit_id", "the default 248 (1 + the link's index)"});
}

TEST(GatewayConfigErrors, NoDuplicateIsClaimedForAValueThatIsAlreadyWrong) {
    // unit_id 300 is an error; its default (2) must not be reported as a duplicate too.
    expect_one_error(
        {"links:\n"
         "  - { name: a, protocol: id2, device: /a, unit_id: 2 }\n"
         "  - { name: b, protocol: id2, device: /b, unit_id: 300 }\n",
         3, "links[1].unit_id", "use 1..247"});
}

TEST(GatewayConfigErrors, DevicesAreDuplicatesWhenTheyResolveToTheSameFile) {
    const auto by_id = [](const std::string& device) {
        return device.starts_with("/dev/serial/by-id/") ? std::string("/dev/ttyUSB0") : device;
    };
    const auto config =
        parse_config(hub + "  - { name: b, protocol: id2, device: /dev/serial/by-id/usb-x }\n",
                     "test.yaml", by_id);
    ASSERT_FALSE(config);
    ASSERT_EQ(config.error().size(), 1u) << describe(config.error());
    EXPECT_EQ(to_string(config.error()[0]),
              "test.yaml:7: links[1].device: device /dev/serial/by-id/usb-x is already used by "
              "link 'hub0' (line 2): both are /dev/ttyUSB0");
    EXPECT_TRUE(parse_config(hub + press, "test.yaml", by_id));
}

TEST(GatewayConfigErrors, ModulesOfALink) {
    expect_one_error({"links:\n  - { name: a, protocol: ioport, device: /d }\n", 2,
                      "links[0].modules", "missing: an ioport link needs at least one module"});
    expect_one_error({"links:\n  - { name: a, protocol: ioport, device: /d, modules: [] }\n", 2,
                      "links[0].modules", "at least one module, found an empty list"});
    expect_one_error({hub + press + "    modules: [{ type: dim16, number: 0 }]\n", 10,
                      "links[1].modules", "an id2 link takes no modules"});
    expect_one_error({hub + "      - dim16\n", 7, "links[0].modules[1]",
                      "expected a mapping such as { type: dim16, number: 0 }"});
}

TEST(GatewayConfigErrors, ModuleKeys) {
    const auto module = [](const std::string& text, const std::string& key,
                           const std::string& fragment) {
        expect_one_error(
            {hub + "      - " + text + "\n", 7, "links[0].modules[1]" + key, fragment});
    };
    module("{ type: dim17, number: 0 }", ".type",
           "use dim16, dom16, acm3p, acm3c, lim16, rgbdm, dccim, dcvim or mux8m");
    module("{ number: 1 }", ".type", "missing: the module type");
    module("{ type: dim16 }", ".number", "missing: the module's address switch 0..7");
    module("{ type: dim16, number: 8 }", ".number", "8 is out of range: use 0..7");
    module("{ type: dim16, number: -1 }", ".number", "use 0..7");
    module("{ type: dom16, number: 0, poll: 1s }", ".poll", "poll is for input modules only");
    module("{ type: dim16, number: 1, initial: 0 }", ".initial",
           "initial is for output modules only (dom16, rgbdm, mux8m): dim16 is an input module");
    module("{ type: acm3c, number: 1, refresh: 1s }", ".refresh",
           "refresh is for output modules only");
    module("{ type: lim16, number: 1, poll: fast }", ".poll", "e.g. 500us");
    module("{ type: dom16, number: 0, initial: 0x10000 }", ".initial",
           "use the 16 outputs as one word 0..0xFFFF");
    module("{ type: dom16, number: 0, initial: red }", ".initial",
           "not an initial value for dom16");
    module("{ type: rgbdm, number: 0, initial: 8 }", ".initial", "use 0-7");
    module("{ type: rgbdm, number: 0, initial: pink }", ".initial",
           "or off, red, green, blue, cyan, magenta, yellow, white");
    module("{ type: mux8m, number: 0, initial: 0x0808 }", ".initial", "pos and neg 0-7");
    module("{ type: mux8m, number: 0, initial: \"0x0102\" }", ".initial",
           "\"0x0102\" is quoted, so it is text");
    module("{ type: dom16, number: 0, refresh: 0 }", ".refresh",
           "0 is too short: use at least 10ms");
    module("{ type: dom16, number: 0, refresh: 5ms }", ".refresh", "use at least 10ms");
    module("{ type: dim16, number: 1, safe: 0 }", ".safe",
           "safe is for output modules only (dom16, rgbdm, mux8m): dim16 is an input module");
    module("{ type: rgbdm, number: 0, safe: pink }", ".safe",
           "'pink' is not a safe value for rgbdm");
    module("{ type: mux8m, number: 0, safe: 0x0808 }", ".safe", "pos and neg 0-7");
}

TEST(GatewayConfigErrors, Tags) {
    const auto module = [](const std::string& text, const std::string& key,
                           const std::string& fragment) {
        expect_one_error(
            {hub + "      - " + text + "\n", 7, "links[0].modules[1]" + key, fragment});
    };
    module("{ type: acm3p, number: 0, name: \"\" }", ".name", "must not be empty");
    module("{ type: acm3p, number: 0, name: " + std::string(65, 'x') + " }", ".name",
           "is 65 bytes long: at most 64 bytes of UTF-8");
    module("{ type: acm3p, number: 0, name: \"a\\tb\" }", ".name",
           "'a\\x09b' has a control character at byte 1");
    module("{ type: acm3p, number: 0, name: [a] }", ".name", "expected a name");
    module("{ type: dim16, number: 1, name: \"dim16 0\" }", ".name",
           "module name 'dim16 0' is already used on this link by dim16 0 at line 6: names must "
           "be unique per link");
    module("{ type: dim16, number: 1, channels: { 0: { unit: V } } }", ".channels",
           "channels is for analog modules only (acm3p, acm3c, dccim, dcvim): dim16 has none");
    module("{ type: acm3p, number: 0, channels: { 3: { unit: V } } }", ".channels",
           "'3' is not a channel number: acm3p has channels 0, 1 and 2");
    module("{ type: dccim, number: 0, channels: { 1: { unit: V } } }", ".channels",
           "dccim has channel 0 only");
    module("{ type: dccim, number: 0, channels: { -1: { unit: V } } }", ".channels",
           "'-1' is not a channel number");
    module("{ type: dccim, number: 0, channels: [ { unit: V } ] }", ".channels",
           "expected a mapping by channel number such as { 0: ... }, found a list");
    module("{ type: dccim, number: 0, channels: { 0: { units: V } } }", ".channels.0.units",
           "unknown key: allowed here are name, unit, scale, range");
    module("{ type: dccim, number: 0, channels: { 0: V } }", ".channels.0",
           "expected a mapping such as { name:");
    module("{ type: dccim, number: 0, channels: { 0: { scale: [4, 4, 0, 100] } } }",
           ".channels.0.scale", "in_lo and in_hi must differ: both are 4");
    module("{ type: dccim, number: 0, channels: { 0: { scale: [4, 20, 1, 1] } } }",
           ".channels.0.scale", "out_lo and out_hi must differ");
    module("{ type: dccim, number: 0, channels: { 0: { scale: [4, 20, 0] } } }",
           ".channels.0.scale", "expected a list of 4 numbers [in_lo, in_hi, out_lo, out_hi]");
    module("{ type: dccim, number: 0, channels: { 0: { scale: [4, 20, 0, \"100\"] } } }",
           ".channels.0.scale", "'100' is not allowed: write a finite number");
    module("{ type: dccim, number: 0, channels: { 0: { scale: [4, 20, 0, .nan] } } }",
           ".channels.0.scale", "'.nan' is not allowed");
    module("{ type: dccim, number: 0, channels: { 0: { scale: [4, 20, 0, 1e999] } } }",
           ".channels.0.scale", "'1e999' is not allowed");
    module("{ type: dccim, number: 0, channels: { 0: { scale: [0, 1e-30, 0, 1e30] } } }",
           ".channels.0.scale", "beyond what a float32 register can hold");
    module("{ type: dccim, number: 0, channels: { 0: { range: [6, 0] } } }", ".channels.0.range",
           "[6, 0]: lo must be less than hi");
    module("{ type: dccim, number: 0, channels: { 0: { unit: \"m\\x85\" } } }", ".channels.0.unit",
           "control character at byte 1");
    module("{ type: dom16, number: 1, inputs: { 0: horn } }", ".inputs",
           "inputs names the inputs of dim16 and lim16: dom16 is an output module, name its "
           "outputs with outputs:");
    module("{ type: rgbdm, number: 1, inputs: { 0: horn } }", ".inputs",
           "rgbdm has no digital "
           "inputs");
    module("{ type: lim16, number: 1, outputs: { 0: horn } }", ".outputs",
           "lim16 is an input module, name its inputs with inputs:");
    module("{ type: mux8m, number: 1, outputs: { 0: horn } }", ".outputs",
           "mux8m has no digital outputs");
    module("{ type: dim16, number: 1, inputs: { 16: door } }", ".inputs",
           "'16' is not a input number: dim16 has inputs 0..15");
    module("{ type: dim16, number: 1, inputs: { 0: \"\" } }", ".inputs.0", "must not be empty");
    module("{ type: dom16, number: 1, outputs: { 0: [a] } }", ".outputs.0",
           "expected a name such as \"pump running\", found a list");
    expect_one_error({hub_for_tags + "        channels:\n          0: { unit: V }\n          00: "
                                     "{ unit: A }\n",
                      10, "links[0].modules[0].channels.0",
                      "duplicate channel: channel 0 is already given at line 9"});
}

TEST(GatewayConfigErrors, IdentityObjects) {
    const auto identity = [](const std::string& text, const std::string& key,
                             const std::string& fragment) {
        expect_one_error(
            {hub + "    identity: " + text + "\n", 7, "links[0].identity" + key, fragment});
    };
    identity("{ model_name: " + std::string(65, 'x') + " }", ".model_name",
             "has 65 characters: use 1 to 64");
    identity("{ model_name: \"\" }", ".model_name", "use 1 to 64");
    identity("{ vendor_name: \"caf\\xe9\" }", ".vendor_name", "not printable ASCII");
    identity("{ major_minor_revision: 2.0 }", ".major_minor_revision",
             "the ioportd version and cannot be set");
    identity("{ serial_number: 7 }", ".serial_number", "unknown key");
    identity("hub8u", "", "expected a mapping");
}

TEST(GatewayConfigErrors, TheHttpSection) {
    expect_one_error({"http:\n  listen: 8502\n" + hub, 2, "http.listen", "has no port"});
    expect_one_error(
        {"http:\n  listen: \"web:80\"\n" + hub, 2, "http.listen", "not an IP address"});
    expect_one_error({"http:\n  allow: [10.0.0.0/33]\n" + hub, 2, "http.allow[0]", "/33"});
    expect_one_error(
        {"http:\n  port: 80\n" + hub, 2, "http.port", "allowed here are listen, allow"});
    expect_one_error({"http: on\n" + hub, 1, "http", "expected a mapping"});
    const auto name = [&](const std::string& list, const std::string& key,
                          const std::string& fragment) {
        expect_one_error(
            {"http:\n  listen: \"127.0.0.1:8502\"\n  server_names: " + list + "\n" + hub, 3, key,
             fragment});
    };
    name("gw.example", "http.server_names", "expected a list of host names");
    name("[ok.example, \"\"]", "http.server_names[1]", "'' is not a host name");
    name("[\"gw\\x01.example\"]", "http.server_names[0]", "'gw\\x01.example' is not a host name");
    name("[\"gw\\n.example\"]", "http.server_names[0]", "'gw\\n.example' is not a host name");
    name("[\"http://gw.example\"]", "http.server_names[0]", "no scheme, port or wildcard");
    name("[\"gw.example:8502\"]", "http.server_names[0]", "not a host name");
    name("[\"*.example\"]", "http.server_names[0]", "not a host name");
    name("[" + std::string(254, 'a') + "]", "http.server_names[0]", "1..253 letters");
    name("[{ name: gw }]", "http.server_names[0]", "expected a host name, found a mapping");
}

TEST(GatewayConfigErrors, TheMqttSection) {
    const std::string mqtt = "mqtt:\n  group_id: g\n  edge_node_id: n\n";  // lines 1-3
    const auto broker = [&](const std::string& url, const std::string& fragment) {
        expect_one_error({mqtt + "  broker: \"" + url + "\"\n" + hub, 4, "mqtt.broker", fragment});
    };
    broker("tcp://1.2.3.4", "not an MQTT URL");
    broker("mqtt://", "no valid host");
    broker("mqtt://a b", "no valid host");
    broker("mqtt://1.2.3.4:0", "1..65535");
    broker("mqtt://[1.2.3.4]", "not an IPv6 address");
    const std::string b = "mqtt:\n  broker: mqtt://127.0.0.1\n";  // lines 1-2
    expect_one_error({b + "  edge_node_id: n\n" + hub, 2, "mqtt.group_id", "missing"});
    expect_one_error({b + "  group_id: a/b\n  edge_node_id: n\n" + hub, 3, "mqtt.group_id",
                      "'a/b' contains '/'"});
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  keepalive: 2s\n" + hub, 5,
                      "mqtt.keepalive", "out of range"});
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  deadband: -1\n" + hub, 5,
                      "mqtt.deadband", "at least 0"});
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  templates: 2\n" + hub, 5,
                      "mqtt.templates", "true or false"});
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  template: true\n" + hub, 5,
                      "mqtt.template", "unknown key"});
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  ca_file: /dev/null\n" + hub, 5,
                      "mqtt.ca_file", "mqtts:// brokers only"});
    const TempFile open_password("pw\n", owner_only | perms::others_read);
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  password_file: " +
                          open_password.path() + "\n" + hub,
                      5, "mqtt.password_file", "readable by every user: chmod o-r"});
    const TempFile empty_password("\n", owner_only);
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  password_file: " +
                          empty_password.path() + "\n" + hub,
                      5, "mqtt.password_file", "is empty"});
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n  password_file: /nonexistent\n" + hub,
                      5, "mqtt.password_file", "No such file"});
    expect_one_error({b + "  group_id: g\n  edge_node_id: n\n" +
                          "links:\n  - { name: \"hub/0\", protocol: ioport, device: /dev/x, "
                          "modules: [{ type: dim16, number: 0 }] }\n",
                      6, "links[0].name", "part of Sparkplug device ids"});
}

TEST(GatewayConfigErrors, TheMqttJsonSection) {
    const std::string j = "mqtt_json:\n  broker: mqtt://127.0.0.1\n";  // lines 1-2
    const auto prefix = [&](const std::string& key, const std::string& value,
                            const std::string& fragment) {
        expect_one_error(
            {j + "  " + key + ": " + value + "\n" + hub, 3, "mqtt_json." + key, fragment});
    };
    prefix("topic_prefix", "\"\"", "must not be empty");
    prefix("topic_prefix", "\"a/+/b\"", "'+', an MQTT wildcard");
    prefix("topic_prefix", "\"a/#\"", "'#', an MQTT wildcard");
    prefix("topic_prefix", "\"/a\"", "empty topic level");
    prefix("topic_prefix", "\"a/\"", "empty topic level");
    prefix("topic_prefix", "\"a//b\"", "empty topic level");
    prefix("topic_prefix", "\"$SYS/x\"", "starts with '$'");
    prefix("topic_prefix", "\"a\\x01b\"", "'a\\x01b' has a control character at byte 1");
    prefix("topic_prefix", std::string(129, 'p'), "129 bytes long: at most 128");
    prefix("discovery_prefix", "\"home+assistant\"", "'+', an MQTT wildcard");
    prefix("discovery", "yes", "use true or false");
    prefix("deadband", "-0.5", "at least 0");
    prefix("keepalive", "1s", "out of range");
    prefix("ca_file", "/dev/null", "mqtts:// brokers only");
    prefix("group_id", "g", "unknown key: allowed here are broker, brokers, client_id");
    expect_one_error(
        {"mqtt_json:\n  broker: tcp://x\n" + hub, 2, "mqtt_json.broker", "not an MQTT URL"});
    expect_one_error({"mqtt_json: mqtt://x\n" + hub, 1, "mqtt_json", "expected a mapping"});
    expect_one_error({j + "links:\n  - { name: \"hub/0\", protocol: ioport, device: /dev/x, "
                          "modules: [{ type: dim16, number: 0 }] }\n",
                      4, "links[0].name", "with mqtt_json on, a link name is a topic level"});
}

TEST(GatewayConfig, SeveralBrokersAndAStore) {
    const auto config = parse(
        "mqtt:\n  brokers: [\"mqtt://10.0.0.5:1883\", \"mqtts://10.0.0.6\"]\n"
        "  group_id: g\n  edge_node_id: n\n"
        "  store: { path: /var/lib/ioportd/sparkplug, max_size: 8MiB, forward_rate: 50 }\n" +
        hub);
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->mqtt->brokers, (std::vector<config::BrokerAddress>{
                                         {false, "10.0.0.5", 1883}, {true, "10.0.0.6", 8883}}));
    EXPECT_EQ(config->mqtt->store,
              (config::StoreSettings{"/var/lib/ioportd/sparkplug", 8U << 20, 50}));
    const auto defaults = parse(
        "mqtt:\n  broker: mqtt://b\n  group_id: g\n  edge_node_id: n\n"
        "  store:\n    path: /s\n" +
        hub);
    ASSERT_TRUE(defaults) << describe(defaults.error());
    EXPECT_EQ(defaults->mqtt->store, (config::StoreSettings{"/s", 64U << 20, 200}));
}

TEST(GatewayConfigErrors, BrokersAndTheStore) {
    const std::string ids = "mqtt:\n  group_id: g\n  edge_node_id: n\n";  // lines 1-3
    const auto brokers = [&](const std::string& value, const std::string& key,
                             const std::string& fragment) {
        expect_one_error({ids + "  brokers: " + value + "\n" + hub, 4, key, fragment});
    };
    brokers("[]", "mqtt.brokers", "at least one broker");
    brokers("mqtt://a", "mqtt.brokers", "expected a list");
    brokers("[\"mqtt://a\", \"tcp://b\"]", "mqtt.brokers[1]", "not an MQTT URL");
    brokers("[\"mqtt://a\", \"mqtt://a:1883\"]", "mqtt.brokers", "mqtt://a:1883 is listed twice");
    std::string many = "[";
    for (int i = 0; i <= 16; ++i)
        many += fmt::format("\"mqtt://b{}\",", i);
    brokers(many + "]", "mqtt.brokers", "at most 16");
    expect_one_error({ids + "  broker: mqtt://a\n  brokers: [\"mqtt://b\"]\n" + hub, 5,
                      "mqtt.brokers", "not both"});
    expect_one_error({ids + "  brokers: [\"mqtt://a\"]\n  ca_file: /dev/null\n" + hub, 5,
                      "mqtt.ca_file", "mqtts:// brokers only"});
    const std::string b = "mqtt:\n  broker: mqtt://a\n  group_id: g\n  edge_node_id: n\n";
    const auto store = [&](const std::string& value, const std::string& key,
                           const std::string& fragment) {
        expect_one_error({b + "  store: " + value + "\n" + hub, 5, key, fragment});
    };
    store("{ max_size: 8MiB }", "mqtt.store.path", "missing");
    store("{ path: relative/dir }", "mqtt.store.path", "not an absolute path");
    store("{ path: /s, max_size: 64MB }", "mqtt.store.max_size", "not a store size");
    store("{ path: /s, max_size: 512KiB }", "mqtt.store.max_size", "1MiB..1GiB");
    store("{ path: /s, max_size: 2048GiB }", "mqtt.store.max_size", "not a store size");
    store("{ path: /s, max_size: 1025MiB }", "mqtt.store.max_size", "1MiB..1GiB");
    store("{ path: /s, forward_rate: 0 }", "mqtt.store.forward_rate", "out of range");
    store("{ path: /s, retention: 1d }", "mqtt.store.retention", "unknown key");
    store("/var/lib/ioportd", "mqtt.store", "expected a mapping");
}

TEST(GatewayConfigErrors, CommLossTimeout) {
    expect_one_error(
        {"modbus:\n  comm_loss_timeout: soon\n" + hub, 2, "modbus.comm_loss_timeout", "e.g."});
}

TEST(GatewayConfigErrors, EveryErrorOfAFileIsReportedInLineOrder) {
    const auto config = parse(R"(modbus:
  listen: "0.0.0.0:70000"
  colour: blue
links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    baud: 9600
    modules:
      - { type: dom16, number: 9 }
      - { type: dim16, number: 0, initial: 1 }
      - type: dim16
        number: 0
        inputs: { 0: "a\x7f" }
  - name: hub0
    protocol: id2
    device: /dev/ttyUSB0
    unit_id: 1
    modules: []
)");
    ASSERT_FALSE(config);
    std::vector<std::pair<int, std::string>> found;
    for (const auto& error : config.error())
        found.emplace_back(error.line, error.key);
    const std::vector<std::pair<int, std::string>> expected{
        {2, "modbus.listen"},
        {3, "modbus.colour"},
        {8, "links[0].baud"},
        {10, "links[0].modules[0].number"},
        {11, "links[0].modules[1].initial"},
        {12, "links[0].modules[2]"},
        {14, "links[0].modules[2].inputs.0"},
        {15, "links[1].name"},
        {17, "links[1].device"},
        {18, "links[1].unit_id"},
        {19, "links[1].modules"},
    };
    EXPECT_EQ(found, expected) << describe(config.error());
}

TEST(GatewayConfigErrors, ToStringNamesFileLineAndKey) {
    EXPECT_EQ(to_string({"ioportd.yaml", 12, "links[0].baud", "9600 is not allowed"}),
              "ioportd.yaml:12: links[0].baud: 9600 is not allowed");
    EXPECT_EQ(to_string({"ioportd.yaml", 0, "links", "the file is empty"}),
              "ioportd.yaml: links: the file is empty");
    EXPECT_EQ(to_string({"ioportd.yaml", 3, "", "YAML syntax error: x"}),
              "ioportd.yaml:3: YAML syntax error: x");
}

TEST(GatewayConfigErrors, AFileThatCannotBeReadIsOneError) {
    const auto config = load_config("/nonexistent/ioportd.yaml", identity);
    ASSERT_FALSE(config);
    ASSERT_EQ(config.error().size(), 1u);
    EXPECT_EQ(to_string(config.error()[0]),
              "/nonexistent/ioportd.yaml: cannot read the file: No such file or directory");
    const auto directory = load_config("/", identity);
    ASSERT_FALSE(directory);
    EXPECT_NE(directory.error()[0].message.find("Is a directory"), std::string::npos);
}

TEST(GatewayConfig, LoadsAFile) {
    char path[] = "/tmp/gateway_config_test_XXXXXX";
    const int fd = mkstemp(path);
    ASSERT_GE(fd, 0);
    close(fd);
    std::ofstream(path) << hub;
    const auto config = load_config(path, identity);
    std::filesystem::remove(path);
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->file, path);
    EXPECT_EQ(config->links[0].name, "hub0");
}

TEST(GatewayConfig, ResolveDeviceFollowsSymlinksAndKeepsPathsItCannotResolve) {
    EXPECT_EQ(resolve_device("/dev/../dev/null"), "/dev/null");
    EXPECT_EQ(resolve_device("/nonexistent/ttyUSB9"), "/nonexistent/ttyUSB9");
}

// --- Networks -------------------------------------------------------------------------------

boost::asio::ip::address ip(const std::string& text) {
    return boost::asio::ip::make_address(text);
}
Network network(const std::string& text) {
    const auto config = parse("modbus: { allow: [\"" + text + "\"] }\n" + hub);
    EXPECT_TRUE(config) << text << (config ? "" : describe(config.error()));
    return config ? config->modbus.allow.at(0) : Network{};
}

TEST(Network, ContainsIpv4) {
    const Network ten = network("10.0.0.0/8");
    EXPECT_TRUE(contains(ten, ip("10.0.0.0")));
    EXPECT_TRUE(contains(ten, ip("10.255.1.2")));
    EXPECT_TRUE(contains(ten, ip("10.255.255.255")));
    EXPECT_FALSE(contains(ten, ip("11.0.0.1")));
    EXPECT_FALSE(contains(ten, ip("9.255.255.255")));
    const Network odd = network("192.168.1.128/25");
    EXPECT_TRUE(contains(odd, ip("192.168.1.200")));
    EXPECT_FALSE(contains(odd, ip("192.168.1.127")));
}

TEST(Network, ABareAddressIsASingleHost) {
    const Network host = network("127.0.0.1");
    EXPECT_EQ(host, (Network{network("127.0.0.1/32").network, "127.0.0.1"}));
    EXPECT_TRUE(host.network.is_host());
    EXPECT_TRUE(contains(host, ip("127.0.0.1")));
    EXPECT_FALSE(contains(host, ip("127.0.0.2")));
    const Network host32 = network("127.0.0.1/32");
    EXPECT_TRUE(contains(host32, ip("127.0.0.1")));
    EXPECT_FALSE(contains(host32, ip("127.0.0.0")));
    const Network v6host = network("::1");
    EXPECT_EQ(v6host.network.prefix_length(), 128);
    EXPECT_TRUE(contains(v6host, ip("::1")));
    EXPECT_FALSE(contains(v6host, ip("::2")));
    EXPECT_TRUE(contains(network("::1/128"), ip("::1")));
}

TEST(Network, ContainsIpv6) {
    const Network ula = network("fd00::/8");
    EXPECT_TRUE(contains(ula, ip("fd12::")));
    EXPECT_FALSE(contains(ula, ip("fe12::")));
    const Network doc = network("2001:db8:1::/48");
    EXPECT_TRUE(contains(doc, ip("2001:db8:1:ff00::")));
    EXPECT_FALSE(contains(doc, ip("2001:db8:2::")));
    // An IPv6 address whose first bytes look like an IPv4 network is not in it.
    EXPECT_FALSE(contains(network("10.0.0.0/8"), ip("a00::")));
    // A link-local client's zone (fe80::1%2, as a socket reports it) takes no part.
    auto zoned = ip("fe80::1").to_v6();
    zoned.scope_id(2);
    EXPECT_TRUE(contains(network("fe80::/10"), boost::asio::ip::address(zoned)));
    EXPECT_TRUE(contains(network("fe80::1"), boost::asio::ip::address(zoned)));
}

TEST(Network, Ipv4MappedAddressesMatchIpv4Networks) {
    EXPECT_TRUE(contains(network("10.0.0.0/8"), ip("::ffff:10.1.2.3")));
    EXPECT_FALSE(contains(network("10.0.0.0/8"), ip("::ffff:11.1.2.3")));
    EXPECT_TRUE(contains(network("127.0.0.1"), ip("::ffff:127.0.0.1")));
    EXPECT_FALSE(contains(network("127.0.0.1"), ip("::ffff:127.0.0.2")));
    EXPECT_TRUE(contains(network("::ffff:10.0.0.0/104"), ip("10.9.9.9")));
    EXPECT_FALSE(contains(network("::ffff:10.0.0.0/104"), ip("12.9.9.9")));
    // Mapped, not compatible: ::10.1.2.3 is no IPv4 client.
    EXPECT_FALSE(contains(network("10.0.0.0/8"), ip("::10.1.2.3")));
}

TEST(Network, PrefixZeroIsEveryoneOfItsFamily) {
    const Network any4 = network("0.0.0.0/0");
    EXPECT_TRUE(contains(any4, ip("1.2.3.4")));
    EXPECT_TRUE(contains(any4, ip("0.0.0.0")));
    EXPECT_TRUE(contains(any4, ip("255.255.255.255")));
    EXPECT_TRUE(contains(any4, ip("::ffff:8.8.8.8")));
    EXPECT_FALSE(contains(any4, ip("2001::")));
    EXPECT_FALSE(contains(any4, ip("::1")));
    const Network any6 = network("::/0");
    EXPECT_TRUE(contains(any6, ip("2001::")));
    EXPECT_TRUE(contains(any6, ip("::")));
    EXPECT_TRUE(contains(any6, ip("ffff:ffff:ffff:ffff:ffff:ffff:ffff:ffff")));
    // IPv4 clients of an IPv6 socket are IPv6 addresses too (::ffff:a.b.c.d).
    EXPECT_TRUE(contains(any6, ip("1.2.3.4")));
    EXPECT_TRUE(contains(any6, ip("::ffff:1.2.3.4")));
}

// --- The example files ----------------------------------------------------------------------

TEST(GatewayConfig, TheExampleFilesAreValid) {
    for (const char* name : {"ioportd.yaml", "ioportd-sim.yaml"}) {
        const auto config =
            load_config(std::string(IOPORTD_SOURCE_DIR) + "/config/" + name, identity);
        ASSERT_TRUE(config) << name << describe(config.error());
        EXPECT_EQ(config->links.size(), 2u) << name;
    }
}

TEST(GatewayConfig, TheProductionExampleServesEveryoneOnPort502) {
    const auto config =
        load_config(std::string(IOPORTD_SOURCE_DIR) + "/config/ioportd.yaml", identity);
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->modbus.listen_host, "0.0.0.0");
    EXPECT_EQ(config->modbus.listen_port, 502);
    // The default, not written: uncommenting `tls` turns plain Modbus (no roles) off.
    EXPECT_FALSE(config->modbus.listen_given);
    EXPECT_TRUE(config->modbus.allow.empty());
    EXPECT_TRUE(config->links.at(0).device.starts_with("/dev/serial/by-id/"));
    EXPECT_EQ(config->links.at(1).protocol, Protocol::id2);
    EXPECT_FALSE(config->mqtt);  // an upgrade never talks to a broker by itself
}

TEST(GatewayConfig, TheSimulatorExampleIsWhatTheDemoExpects) {
    const auto config =
        load_config(std::string(IOPORTD_SOURCE_DIR) + "/config/ioportd-sim.yaml", identity);
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->modbus.listen_host, "127.0.0.1");
    EXPECT_EQ(config->modbus.listen_port, 1502);
    const LinkConfig& hub0 = config->links.at(0);
    EXPECT_EQ(hub0.name, "hub0");
    EXPECT_EQ(hub0.device, "/tmp/ioportd-sim/ttyIOPORT0");
    EXPECT_EQ(hub0.unit_id, 1);
    EXPECT_EQ(hub0.modules.size(), 8u);
    // Names, a unit and a scale, as the README's first screen and scripts/demo --check show.
    const auto& dim16 = hub0.modules.at(0).tags;
    EXPECT_EQ(dim16.points[0], "door open");
    EXPECT_EQ(dim16.points[15], "pump running");
    const auto& acm3p = hub0.modules.at(2).tags;
    EXPECT_EQ(acm3p.name, "boiler 1");
    EXPECT_EQ(acm3p.channels.at(0).name, "supply temperature");
    EXPECT_EQ(acm3p.channels.at(0).unit, "°C");
    EXPECT_EQ(acm3p.channels.at(0).scale, (gateway::Scale{0, 100, -20, 150}));
    const LinkConfig& id2 = config->links.at(1);
    EXPECT_EQ(id2.name, "press");
    EXPECT_EQ(id2.protocol, Protocol::id2);
    EXPECT_EQ(id2.device, "/tmp/ioportd-sim/ttyID2");
    EXPECT_EQ(id2.unit_id, 2);
    ASSERT_TRUE(config->http);  // the demo prints this page's address
    EXPECT_EQ(config->http->listen_port, 8502);
    ASSERT_TRUE(config->mqtt);  // the demo starts a broker here
    EXPECT_EQ(config->mqtt->brokers,
              (std::vector<config::BrokerAddress>{{false, "127.0.0.1", 1883}}));
}

// Issue 37: ids made safe for MQTT once collided. Default client ids are escaped (unambiguous,
// also between two gateways); two links whose Home Assistant ids would be one are an error, and
// so is one client id for both sections on a broker they share.
TEST(GatewayConfig, IdsThatLeaveTheBoxStayApart) {
    const std::string links = R"(links:
  - { name: hub0, protocol: ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }
)";
    const auto client_id = [&](const std::string& section) {
        const auto config = parse(section + links);
        EXPECT_TRUE(config) << describe(config.error());
        return config->mqtt ? config->mqtt->client_id : config->mqtt_json->connection.client_id;
    };
    const auto sparkplug = [&](const std::string& group, const std::string& node) {
        return client_id("mqtt:\n  broker: mqtt://b\n  group_id: " + group +
                         "\n  edge_node_id: " + node + "\n");
    };
    EXPECT_EQ(sparkplug("a-b", "c"), "ioportd-a_2Db-c");
    EXPECT_EQ(sparkplug("a", "b-c"), "ioportd-a-b_2Dc");
    const auto json = [&](const std::string& prefix) {
        return client_id("mqtt_json:\n  broker: mqtt://b\n  topic_prefix: \"" + prefix + "\"\n");
    };
    EXPECT_EQ(json("plant/line1"), "ioportd-json_plant_2Fline1");
    EXPECT_EQ(json("plant_line1"), "ioportd-json_plant_5Fline1");
    // Never a Sparkplug node's: one '-' where those have two.
    EXPECT_NE(json("x"), sparkplug("json", "x"));

    expect_one_error(
        {R"(mqtt_json: { broker: "mqtt://b" }
links:
  - { name: hub.0, protocol: ioport, device: /dev/ttyUSB0, modules: [{ type: dim16, number: 0 }] }
  - { name: hub_0, protocol: ioport, device: /dev/ttyUSB1, modules: [{ type: dim16, number: 0 }] }
)",
         4, "links[1].name",
         "'hub_0' and links[0].name 'hub.0' are the same id 'hub_0' in Home Assistant"});
    expect_one_error(
        {"mqtt: { broker: \"mqtt://b\", group_id: g, edge_node_id: n, client_id: x }\n"
         "mqtt_json:\n  broker: \"mqtt://b\"\n  client_id: x\n" +
             links,
         4, "mqtt_json.client_id", "'x' is mqtt.client_id too, on the same broker mqtt://b:1883"});
    EXPECT_TRUE(
        parse("mqtt: { broker: \"mqtt://b\", group_id: g, edge_node_id: n, client_id: x }\n"
              "mqtt_json:\n  broker: \"mqtt://c\"\n  client_id: x\n" +
              links));
}

}  // namespace

// --- Modbus/TCP Security (gateway.md §5.6) -------------------------------------------------

// The TLS files of a test: the fixtures' certificate, key and CA in files of their own.
struct TlsFiles {
    TempFile certificate{test::tls_fixtures::server_pem, owner_only};
    TempFile key{test::tls_fixtures::server_key, owner_only | perms::group_read};
    TempFile ca{test::tls_fixtures::ca_pem, owner_only | perms::group_read | perms::others_read};

    // modbus: with a tls: section, lines 1-7, then `extra` (at line 8 on) and the hub.
    std::string yaml(const std::string& extra =
                         "    roles:\n      operator: { units: all, access: read_write }\n") const {
        return "modbus:\n  listen: \"\"\n  tls:\n    listen: \"127.0.0.1:802\"\n"
               "    certificate: " +
               certificate.path() + "\n    key: " + key.path() + "\n    client_ca: " + ca.path() +
               "\n" + extra + hub;
    }
};

TEST(GatewayConfig, TheTlsSection) {
    const TlsFiles files;
    const auto config = parse(files.yaml(
        "    default_role: viewer\n    roles:\n      operator: { units: all, access: read_write }\n"
        "      viewer: { units: [1], access: read }\n"));
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_FALSE(config->modbus.plain());
    ASSERT_TRUE(config->modbus.tls);
    const auto& tls = *config->modbus.tls;
    EXPECT_EQ(tls.listen_host, "127.0.0.1");
    EXPECT_EQ(tls.listen_port, 802);
    EXPECT_EQ(tls.certificate_pem, test::tls_fixtures::server_pem);
    EXPECT_EQ(tls.key_pem, test::tls_fixtures::server_key);
    EXPECT_EQ(tls.client_ca_pem, test::tls_fixtures::ca_pem);
    EXPECT_EQ(tls.default_role, "viewer");
    ASSERT_EQ(tls.roles.size(), 2u);
    EXPECT_TRUE(tls.roles.at("operator").units.all());
    EXPECT_EQ(tls.roles.at("operator").access, modbus_security::Access::read_write);
    EXPECT_EQ(tls.roles.at("viewer").units.count(), 1u);
    EXPECT_TRUE(tls.roles.at("viewer").units.test(1));
    EXPECT_EQ(tls.roles.at("viewer").access, modbus_security::Access::read);
    EXPECT_EQ(tls.max_handshakes, 16);
    EXPECT_TRUE(tls.client_crl.empty());
    EXPECT_TRUE(tls.client_crl_pem.empty());
    // Absent, or without listen: off; the plain listener's default stays.
    const auto off = parse("modbus:\n  tls:\n    certificate: /nonexistent\n" + hub);
    ASSERT_TRUE(off) << describe(off.error());
    EXPECT_FALSE(off->modbus.tls);
    EXPECT_TRUE(off->modbus.plain());
    EXPECT_FALSE(parse(hub)->modbus.tls);
}

TEST(GatewayConfigErrors, TheTlsSection) {
    const TlsFiles files;
    const std::string roles = "    roles:\n      operator: { units: all, access: read_write }\n";
    // Lines: 5 certificate, 6 key, 7 client_ca, 8 on what is added.
    expect_one_error({files.yaml("    default_role: admin\n" + roles), 8, "modbus.tls.default_role",
                      "'admin' is not one of the roles: give one of operator"});
    expect_one_error({files.yaml(""), 4, "modbus.tls.roles", "missing"});
    expect_one_error({files.yaml("    roles: {}\n"), 8, "modbus.tls.roles", "an empty mapping"});
    expect_one_error({files.yaml("    roles:\n      op: { units: all }\n"), 9,
                      "modbus.tls.roles.op.access", "missing: read or read_write"});
    expect_one_error({files.yaml("    roles:\n      op: { units: all, access: write }\n"), 9,
                      "modbus.tls.roles.op.access",
                      "'write' is not allowed: use read or read_write"});
    expect_one_error({files.yaml("    roles:\n      op: { units: [], access: read }\n"), 9,
                      "modbus.tls.roles.op.units", "an empty list"});
    expect_one_error({files.yaml("    roles:\n      op: { units: \"all\", access: read }\n"), 9,
                      "modbus.tls.roles.op.units", "expected all, or a list"});
    expect_one_error({files.yaml("    roles:\n      op: { units: [1, 0], access: read }\n"), 9,
                      "modbus.tls.roles.op.units[1]", "out of range: use 1..247"});
    expect_one_error({files.yaml("    roles:\n      op: { units: [1, 9], access: read }\n"), 9,
                      "modbus.tls.roles.op.units[1]", "no link has unit id 9"});
    expect_one_error({files.yaml("    roles:\n      op: { units: all, access: read, x: 1 }\n"), 9,
                      "modbus.tls.roles.op.x", "unknown key"});
    expect_one_error({files.yaml(roles + "    ciphers: ALL\n"), 10, "modbus.tls.ciphers",
                      "unknown key: allowed here are listen, certificate, key, client_ca, "
                      "client_crl, max_handshakes, default_role, roles"});
    expect_one_error({files.yaml("    max_handshakes: 0\n" + roles), 8, "modbus.tls.max_handshakes",
                      "out of range: use 1..1024"});
    // The files.
    const auto with = [&](const std::string& certificate, const std::string& key,
                          const std::string& ca) {
        return "modbus:\n  tls:\n    listen: \"127.0.0.1:802\"\n    certificate: " + certificate +
               "\n    key: " + key + "\n    client_ca: " + ca + "\n" + roles + hub;
    };
    const auto& c = files.certificate.path();
    const auto& k = files.key.path();
    const auto& a = files.ca.path();
    expect_one_error({with("/nonexistent/server.pem", k, a), 4, "modbus.tls.certificate",
                      "/nonexistent/server.pem: No such file or directory"});
    expect_one_error({with(c, "/nonexistent/server.key", a), 5, "modbus.tls.key",
                      "/nonexistent/server.key: No such file or directory"});
    expect_one_error({with(c, k, "/nonexistent/ca.pem"), 6, "modbus.tls.client_ca",
                      "/nonexistent/ca.pem: No such file or directory"});
    const TempFile readable_key(test::tls_fixtures::server_key, owner_only | perms::others_read);
    expect_one_error({with(c, readable_key.path(), a), 5, "modbus.tls.key",
                      "readable by every user: chmod o-r " + readable_key.path()});
    const TempFile other_key(test::tls_fixtures::other_key, owner_only);
    expect_one_error(
        {with(c, other_key.path(), a), 5, "modbus.tls.key", "is not the key of the certificate"});
    const TempFile not_pem("hello\n", owner_only);
    expect_one_error(
        {with(not_pem.path(), k, a), 4, "modbus.tls.certificate", "has no PEM certificate"});
    expect_one_error(
        {with(c, not_pem.path(), a), 5, "modbus.tls.key", "is not an unencrypted PEM private key"});
    expect_one_error(
        {with(c, k, not_pem.path()), 6, "modbus.tls.client_ca", "has no PEM certificate"});
    std::string broken = test::tls_fixtures::server_pem;
    broken[100] = broken[100] == 'A' ? 'B' : 'A';
    const TempFile damaged(broken, owner_only);
    expect_one_error(
        {with(damaged.path(), k, a), 4, "modbus.tls.certificate", "certificate 1 does not parse"});
    expect_one_error({with("/tmp", k, a), 4, "modbus.tls.certificate", "/tmp is not a file"});
    expect_one_error({"modbus:\n  tls:\n    listen: \"127.0.0.1:802\"\n    key: " + k +
                          "\n    client_ca: " + a + "\n" + roles + hub,
                      3, "modbus.tls.certificate", "missing: the server's certificate"});
}

// With modbus.tls, plain Modbus (which bypasses the roles) runs only when modbus.listen is given;
// both on is a warning.
TEST(GatewayConfig, PlainModbusBesideTlsOnlyWhenListenIsGiven) {
    const TlsFiles files;
    const std::string tls =
        "  tls:\n    listen: \"127.0.0.1:802\"\n    certificate: " + files.certificate.path() +
        "\n    key: " + files.key.path() + "\n    client_ca: " + files.ca.path() +
        "\n    max_handshakes: 8\n    roles: { op: { units: all, access: "
        "read } }\n";
    const auto implicit = parse("modbus:\n  max_connections: 4\n" + tls + hub);
    ASSERT_TRUE(implicit) << describe(implicit.error());
    EXPECT_FALSE(implicit->modbus.plain());
    EXPECT_FALSE(implicit->modbus.listen_given);
    EXPECT_EQ(implicit->modbus.tls->max_handshakes, 8);
    EXPECT_TRUE(warnings(*implicit).empty());

    const auto both = parse("modbus:\n  listen: \"0.0.0.0:502\"\n" + tls + hub);
    ASSERT_TRUE(both) << describe(both.error());
    EXPECT_TRUE(both->modbus.plain());
    EXPECT_TRUE(both->modbus.listen_given);
    ASSERT_EQ(warnings(*both).size(), 1u);
    EXPECT_EQ(warnings(*both)[0],
              "plain Modbus TCP (modbus.listen \"0.0.0.0:502\") bypasses the roles of "
              "Modbus/TCP Security: any client that reaches it may read and write every unit. "
              "Remove modbus.listen, or set it to \"\", to serve TLS clients only");

    const auto off = parse("modbus:\n  listen: \"\"\n" + tls + hub);
    ASSERT_TRUE(off) << describe(off.error());
    EXPECT_FALSE(off->modbus.plain());
    EXPECT_TRUE(warnings(*off).empty());
    // Without TLS the default stays, and nothing is weakened.
    const auto plain = parse(hub);
    EXPECT_TRUE(plain->modbus.plain());
    EXPECT_TRUE(warnings(*plain).empty());
}

TEST(GatewayConfig, APasswordOverPlainMqttIsAWarning) {
    const TempFile password("s3cret\n", owner_only);
    const auto with = [&](const std::string& broker) {
        return parse("mqtt:\n  broker: \"" + broker +
                     "\"\n  group_id: g\n  edge_node_id: n\n  password_file: " + password.path() +
                     "\n" + hub);
    };
    const auto plain = with("mqtt://broker.plant.example");
    ASSERT_TRUE(plain) << describe(plain.error());
    ASSERT_EQ(warnings(*plain).size(), 1u);
    EXPECT_NE(warnings(*plain)[0].find("goes to the broker broker.plant.example unencrypted over "
                                       "mqtt://"),
              std::string::npos)
        << warnings(*plain)[0];
    const auto tls = with("mqtts://broker.plant.example");
    ASSERT_TRUE(tls) << describe(tls.error());
    EXPECT_TRUE(warnings(*tls).empty());
    const auto no_password = parse(
        "mqtt:\n  broker: \"mqtt://b\"\n  group_id: g\n"
        "  edge_node_id: n\n" +
        hub);
    ASSERT_TRUE(no_password) << describe(no_password.error());
    EXPECT_TRUE(warnings(*no_password).empty());
}

// --- client_crl -----------------------------------------------------------------------------

namespace {

// A tls section with `crl` as client_crl (line 7) and `ca` as client_ca.
std::string with_crl(const TlsFiles& files, const std::string& crl, const std::string& ca = {}) {
    return "modbus:\n  tls:\n    listen: \"127.0.0.1:802\"\n    certificate: " +
           files.certificate.path() + "\n    key: " + files.key.path() +
           "\n    client_ca: " + (ca.empty() ? files.ca.path() : ca) + "\n    client_crl: " + crl +
           "\n    roles: { op: { units: all, access: read } }\n" + hub;
}

}  // namespace

TEST(GatewayConfig, AClientCrlIsReadWithTheTlsFiles) {
    const TlsFiles files;
    const TempFile crl(test::tls_fixtures::crl_pem, owner_only | perms::group_read);
    const auto config = parse(with_crl(files, crl.path()));
    ASSERT_TRUE(config) << describe(config.error());
    EXPECT_EQ(config->modbus.tls->client_crl, crl.path());
    EXPECT_EQ(config->modbus.tls->client_crl_pem, test::tls_fixtures::crl_pem);
}

TEST(GatewayConfigErrors, ABadClientCrl) {
    const TlsFiles files;
    const auto error = [&](const std::string& crl, const std::string& fragment,
                           const std::string& ca = {}) {
        expect_one_error({with_crl(files, crl, ca), 7, "modbus.tls.client_crl", fragment});
    };
    error("/nonexistent/crl.pem", "/nonexistent/crl.pem: No such file or directory");
    const TempFile hello("hello\n", owner_only);
    error(hello.path(), "has no PEM CRL (-----BEGIN X509 CRL-----): make one with openssl ca");
    // A certificate is no CRL.
    error(files.ca.path(), "has no PEM CRL");
    std::string broken = test::tls_fixtures::crl_pem;
    broken[60] = broken[60] == 'A' ? 'B' : 'A';
    const TempFile damaged(broken, owner_only);
    error(damaged.path(), "CRL 1 does not parse");
    // Same issuer name, another key: not signed by client_ca.
    const TempFile impostor(test::tls_fixtures::impostor_crl_pem, owner_only);
    error(impostor.path(),
          "CRL 1 (issuer CN=ioportd unit-test CA) is not signed by a CA of "
          "client_ca " +
              files.ca.path());
    const TempFile expired(test::tls_fixtures::expired_crl_pem, owner_only);
    error(expired.path(),
          "CRL 1 (issuer CN=ioportd unit-test CA) expired at 2020-02-01 00:00:00 "
          "UTC (its nextUpdate)");
    const TempFile too_big(
        std::string(test::tls_fixtures::crl_pem) + std::string(std::size_t{1024} * 1024, '\n'),
        owner_only);
    error(too_big.path(), "is larger than 1024 KiB: not a PEM CRL");
    // A second CA in client_ca without a CRL: its clients would all be refused.
    const TempFile two_cas(std::string(test::tls_fixtures::ca_pem) + test::tls_fixtures::server_pem,
                           owner_only);
    const TempFile crl(test::tls_fixtures::crl_pem, owner_only);
    error(crl.path(), "has no CRL of CN=unit-test gateway, a CA in client_ca " + two_cas.path(),
          two_cas.path());
}

// --- Files that grant rights (gateway.md §5.6) -----------------------------------------------

// Each file that grants rights, group- or world-writable, is an error naming it.
TEST(GatewayConfigErrors, AFileThatGrantsRightsMustNotBeWritableByGroupOrOthers) {
    const TlsFiles files;
    const TempFile crl(test::tls_fixtures::crl_pem, owner_only);
    for (const auto writable : {perms::group_write, perms::others_write}) {
        const char* who = writable == perms::group_write ? "its group" : "every user";
        SCOPED_TRACE(who);
        const TempFile certificate(test::tls_fixtures::server_pem, owner_only | writable);
        const TempFile key(test::tls_fixtures::server_key, owner_only | writable);
        const TempFile ca(test::tls_fixtures::ca_pem, owner_only | perms::others_read | writable);
        const TempFile open_crl(test::tls_fixtures::crl_pem, owner_only | writable);
        const TempFile password("pw\n", owner_only | writable);
        const auto tls = [&](const std::string& c, const std::string& k, const std::string& a,
                             const std::string& r) {
            return "modbus:\n  tls:\n    listen: \"127.0.0.1:802\"\n    certificate: " + c +
                   "\n    key: " + k + "\n    client_ca: " + a + "\n    client_crl: " + r +
                   "\n    roles: { op: { units: all, access: read } }\n" + hub;
        };
        const auto& c = files.certificate.path();
        const auto& k = files.key.path();
        const auto& a = files.ca.path();
        const auto& r = crl.path();
        const auto message = [&](const TempFile& file) {
            return file.path() + " is writable by " + who;
        };
        expect_one_error(
            {tls(certificate.path(), k, a, r), 4, "modbus.tls.certificate", message(certificate)});
        expect_one_error({tls(c, key.path(), a, r), 5, "modbus.tls.key", message(key)});
        expect_one_error({tls(c, k, ca.path(), r), 6, "modbus.tls.client_ca", message(ca)});
        expect_one_error(
            {tls(c, k, a, open_crl.path()), 7, "modbus.tls.client_crl", message(open_crl)});
        expect_one_error(
            {"mqtt:\n  broker: \"mqtts://b\"\n  group_id: g\n  edge_node_id: n\n"
             "  password_file: " +
                 password.path() + "\n" + hub,
             5, "mqtt.password_file", message(password)});
        // The configuration itself.
        const TempFile config(hub, owner_only | perms::group_read | perms::others_read | writable);
        const auto loaded = load_config(config.path(), identity);
        ASSERT_FALSE(loaded);
        ASSERT_EQ(loaded.error().size(), 1u);
        EXPECT_EQ(loaded.error()[0].file, config.path());
        EXPECT_EQ(loaded.error()[0].line, 0);
        EXPECT_EQ(
            loaded.error()[0].message.find("is writable by " + std::string(who) + " (mode 06"), 0u)
            << to_string(loaded.error()[0]);
        EXPECT_NE(loaded.error()[0].message.find("chmod go-w " + config.path()), std::string::npos);
    }
    // Readable by all is fine for what is not secret, as the CA above and the config here.
    const TempFile config(hub, owner_only | perms::group_read | perms::others_read);
    const auto loaded = load_config(config.path(), identity);
    EXPECT_TRUE(loaded) << describe(loaded.error());
}

// --- http.web_config_file (gateway.md §7.1) ----------------------------------------------------

// A web configuration in a file of the test's, beside the TLS files (so that their names alone,
// relative paths, are its neighbours), and the main file that names it.
struct WebFiles {
    TlsFiles tls;
    std::unique_ptr<TempFile> web;

    // `operators` and `listen` as the http: section's keys, on lines 2 and 3.
    explicit WebFiles(const std::string& content, perms mode = owner_only)
        : web(std::make_unique<TempFile>(content, mode)) {}
    std::string yaml(const std::string& operators = "[alice]",
                     const std::string& listen = "127.0.0.1:8502") const {
        return "http:\n  web_config_file: " + web->path() + "\n  operators: " + operators +
               "\n  listen: \"" + listen + "\"\n" + hub;
    }
    std::string name(const TempFile& file) const {
        return std::filesystem::path(file.path()).filename().string();
    }
};

constexpr const char* alice_hash = "$2y$04$sGO5GKf0dpvOcga0RM2/Ye037FPBgYeYLDPwBpx1VY2vk.4fZO5JW";
constexpr const char* bob_hash = "$2b$10$d7enEMjJTTVxEJCW4OtbheqMos5ISD.cKh7EOO3YKSbYPpclm3qVa";
// bob's salt and checksum under cost 4 and 13: what is read of a hash is its form and its cost.
constexpr const char* grafana_hash = "$2b$04$d7enEMjJTTVxEJCW4OtbheqMos5ISD.cKh7EOO3YKSbYPpclm3qVa";
constexpr const char* slow_hash = "$2b$13$d7enEMjJTTVxEJCW4OtbheqMos5ISD.cKh7EOO3YKSbYPpclm3qVa";

// The errors of a main file whose web configuration is `web`: each must name the web file.
std::vector<ConfigError> web_errors(const WebFiles& files,
                                    const std::string& operators = "[alice]") {
    const auto config = parse(files.yaml(operators));
    if (config) return {};
    return config.error();
}

void expect_web_error(const std::string& web, int line, const std::string& key,
                      const std::string& fragment) {
    SCOPED_TRACE(web);
    const WebFiles files(web);
    const auto errors = web_errors(files);
    ASSERT_EQ(errors.size(), 1u) << describe(errors);
    EXPECT_EQ(errors[0].file, files.web->path());
    EXPECT_EQ(errors[0].line, line) << to_string(errors[0]);
    EXPECT_EQ(errors[0].key, key) << to_string(errors[0]);
    EXPECT_NE(errors[0].message.find(fragment), std::string::npos)
        << to_string(errors[0]) << "\n  should contain: " << fragment;
}

TEST(GatewayConfig, TheWebConfigurationAsTheExporterToolkitWritesIt) {
    const TlsFiles tls;
    const WebFiles probe("");
    // cert_file and key_file relative: beside the web file; client_ca_file absolute.
    const WebFiles files("tls_server_config:\n  cert_file: " + probe.name(tls.certificate) +
                         "\n  key_file: " + probe.name(tls.key) +
                         "\n  client_ca_file: " + tls.ca.path() +
                         "\n  client_auth_type: VerifyClientCertIfGiven\n"
                         "  min_version: TLS13\n"
                         "http_server_config:\n  http2: false\n  headers:\n"
                         "    Strict-Transport-Security: max-age=31536000\n"
                         "    X-Frame-Options: \"\"\n"
                         "basic_auth_users:\n  alice: " +
                         std::string(alice_hash) + "\n  grafana: " + grafana_hash + "\n");
    const auto config = parse(files.yaml("[alice]", "0.0.0.0:8443"));
    ASSERT_TRUE(config) << describe(config.error());
    ASSERT_TRUE(config->http && config->http->web);
    const auto& web = *config->http->web;
    EXPECT_EQ(web.path, files.web->path());
    ASSERT_TRUE(web.tls);
    EXPECT_EQ(web.tls->cert_file, tls.certificate.path());
    EXPECT_EQ(web.tls->cert_pem, test::tls_fixtures::server_pem);
    EXPECT_EQ(web.tls->key_pem, test::tls_fixtures::server_key);
    EXPECT_EQ(web.tls->client_ca_pem, test::tls_fixtures::ca_pem);
    EXPECT_EQ(web.tls->client_auth, ClientAuth::verify_if_given);
    EXPECT_EQ(web.tls->min_version, TlsVersion::tls13);
    EXPECT_EQ(web.tls->max_version, TlsVersion::tls13);
    // A blank value unsets the header, as the exporter-toolkit says.
    EXPECT_EQ(web.headers, (std::vector<std::pair<std::string, std::string>>{
                               {"Strict-Transport-Security", "max-age=31536000"}}));
    EXPECT_EQ(web.users, (std::map<std::string, std::string>{{"alice", alice_hash},
                                                             {"grafana", grafana_hash}}));
    EXPECT_EQ(config->http->operators, (std::vector<std::string>{"alice"}));
    EXPECT_EQ(config->http->ipv6_prefix, 64);
    // Passwords over TLS off loopback, of one cost: nothing to warn of.
    EXPECT_TRUE(warnings(*config).empty()) << fmt::format("{}", fmt::join(warnings(*config), "\n"));

    // An empty file is one without TLS and users: plain, anyone reads, no one writes.
    const WebFiles empty("");
    const auto plain = parse(empty.yaml("[]"));
    ASSERT_TRUE(plain) << describe(plain.error());
    ASSERT_TRUE(plain->http->web);
    EXPECT_FALSE(plain->http->web->tls);
    EXPECT_TRUE(plain->http->web->users.empty());
}

// Off loopback, whoever reaches the port reads everything unless every request names a user.
TEST(GatewayConfig, AnHttpSideOffLoopbackWithoutUsersIsAWarning) {
    const auto warned = [](const std::string& yaml) {
        const auto config = parse(yaml);
        EXPECT_TRUE(config) << describe(config.error());
        return config && std::ranges::any_of(warnings(*config), [](const std::string& w) {
                   return w.find("open to whoever reaches it") != std::string::npos;
               });
    };
    EXPECT_TRUE(warned("http: { listen: \"0.0.0.0:8502\" }\n" + hub));
    EXPECT_TRUE(warned("http: { listen: \"[::]:8502\" }\n" + hub));
    EXPECT_FALSE(warned("http: { listen: \"127.0.0.1:8502\" }\n" + hub));
    EXPECT_FALSE(warned("http: { listen: \"[::1]:8502\" }\n" + hub));
    EXPECT_FALSE(warned("http: { listen: \"localhost:8502\" }\n" + hub));
    const WebFiles empty("");
    EXPECT_TRUE(warned(empty.yaml("[]", "0.0.0.0:8502")));
    const WebFiles users("basic_auth_users: { alice: " + std::string(alice_hash) + " }\n");
    EXPECT_FALSE(warned(users.yaml("[]", "0.0.0.0:8502")));
    const TlsFiles tls;
    const auto certificates = [&](const std::string& auth) {
        return "tls_server_config:\n  cert_file: " + tls.certificate.path() +
               "\n  key_file: " + tls.key.path() + "\n  client_ca_file: " + tls.ca.path() +
               "\n  client_auth_type: " + auth + "\n";
    };
    const WebFiles verified(certificates("RequireAndVerifyClientCert"));
    EXPECT_FALSE(warned(verified.yaml("[]", "0.0.0.0:8502")));
    const WebFiles optional(certificates("VerifyClientCertIfGiven"));
    EXPECT_TRUE(warned(optional.yaml("[]", "0.0.0.0:8502")));
}

// gateway.md §7.5: what a password check costs, and passwords that cross the network readable.
TEST(GatewayConfig, PasswordsInClearMixedCostsAndSlowHashesAreWarnings) {
    const auto warned = [](const WebFiles& files, const std::string& listen,
                           const std::string& fragment) {
        const auto config = parse(files.yaml("[]", listen));
        EXPECT_TRUE(config) << describe(config.error());
        return config && std::ranges::any_of(warnings(*config), [&](const std::string& w) {
                   return w.find(fragment) != std::string::npos;
               });
    };
    const std::string users = "basic_auth_users:\n  alice: " + std::string(alice_hash) + "\n";
    const WebFiles plain(users);
    constexpr auto readable = "cross the network readable";
    EXPECT_TRUE(warned(plain, "0.0.0.0:8502", readable));
    EXPECT_TRUE(warned(plain, "[::]:8502", readable));
    EXPECT_FALSE(warned(plain, "127.0.0.1:8502", readable));
    EXPECT_FALSE(warned(plain, "[::1]:8502", readable));
    const TlsFiles tls;
    const WebFiles secure("tls_server_config:\n  cert_file: " + tls.certificate.path() +
                          "\n  key_file: " + tls.key.path() + "\n" + users);
    EXPECT_FALSE(warned(secure, "0.0.0.0:8502", readable));

    const WebFiles mixed(users + "  bob: " + bob_hash + "\n  grafana: " + grafana_hash + "\n");
    EXPECT_TRUE(
        warned(mixed, "127.0.0.1:8502", "have different costs: 4 (alice, grafana), 10 (bob)"));
    EXPECT_FALSE(warned(plain, "127.0.0.1:8502", "different costs"));
    const WebFiles slow("basic_auth_users:\n  carol: " + std::string(slow_hash) + "\n");
    EXPECT_TRUE(warned(slow, "127.0.0.1:8502",
                       "the bcrypt hash of carol in " + slow.web->path() +
                           " has cost 13: each check of its password is "
                           "8 times the work of cost 10"));
    EXPECT_FALSE(warned(mixed, "127.0.0.1:8502", "has cost"));
}

TEST(GatewayConfig, Ipv6PrefixIs64To128) {
    const auto with = [](const std::string& prefix) {
        return parse("http:\n  listen: \"127.0.0.1:8502\"\n  ipv6_prefix: " + prefix + "\n" + hub);
    };
    ASSERT_TRUE(with("128"));
    EXPECT_EQ(with("128")->http->ipv6_prefix, 128);
    EXPECT_EQ(with("72")->http->ipv6_prefix, 72);
    expect_one_error({"http:\n  ipv6_prefix: 48\n" + hub, 2, "http.ipv6_prefix", "64..128"});
    expect_one_error({"http:\n  ipv6_prefix: 129\n" + hub, 2, "http.ipv6_prefix", "64..128"});
}

// As sshd checks its files: a file that grants rights owned by anyone but root or this process's
// user is one its owner can change (its mode too), and so an error naming it and its owner.
TEST(GatewayConfigErrors, AFileThatGrantsRightsOwnedByAnotherUserIsAnError) {
    if (::geteuid() != 0) GTEST_SKIP() << "giving a file to another user needs root";
    constexpr uid_t nobody = 65534;
    const auto give = [](const TempFile& file) {
        ASSERT_EQ(::chown(file.path().c_str(), nobody, static_cast<gid_t>(-1)), 0);
    };
    const TempFile config(hub, owner_only);
    give(config);
    const auto loaded = load_config(config.path(), identity);
    ASSERT_FALSE(loaded);
    ASSERT_EQ(loaded.error().size(), 1u);
    EXPECT_EQ(loaded.error()[0].file, config.path());
    EXPECT_EQ(loaded.error()[0].message.find("is owned by nobody (uid 65534), neither root nor "
                                             "root (uid 0), the user ioportd runs as"),
              0u)
        << to_string(loaded.error()[0]);
    EXPECT_NE(loaded.error()[0].message.find("chown root " + config.path()), std::string::npos);
    const WebFiles web("basic_auth_users:\n  alice: " + std::string(alice_hash) + "\n");
    give(*web.web);
    const auto errors = web_errors(web);
    ASSERT_EQ(errors.size(), 1u) << describe(errors);
    EXPECT_NE(errors[0].message.find("is owned by nobody (uid 65534)"), std::string::npos);
    const TlsFiles tls;
    give(tls.key);
    expect_one_error({"modbus:\n  tls:\n    listen: \"127.0.0.1:802\"\n    certificate: " +
                          tls.certificate.path() + "\n    key: " + tls.key.path() +
                          "\n    client_ca: " + tls.ca.path() +
                          "\n    roles: { op: { units: all, access: read } }\n" + hub,
                      5, "modbus.tls.key", tls.key.path() + " is owned by nobody"});
}

TEST(GatewayConfigErrors, TheWebConfigurationIsReadStrictlyAndItsErrorsNameIt) {
    const std::string alice = std::string("basic_auth_users:\n  alice: ") + alice_hash + "\n";
    expect_web_error(alice + "tls_config: {}\n", 3, "tls_config",
                     "unknown key: allowed here are tls_server_config");
    expect_web_error(alice + "rate_limit: { interval: 1s }\n", 3, "rate_limit",
                     "does not implement this key");
    expect_web_error("basic_auth_users:\n  alice: secret\n", 2, "basic_auth_users.alice",
                     "expected a bcrypt hash");
    expect_web_error("basic_auth_users:\n  alice: $1$abc$defghijklmnop\n", 2,
                     "basic_auth_users.alice", "htpasswd -nBC 10");
    expect_web_error("basic_auth_users:\n  alice: " + std::string(alice_hash).substr(0, 59) + "\n",
                     2, "basic_auth_users.alice", "expected a bcrypt hash");
    expect_web_error("basic_auth_users: [alice]\n", 1, "basic_auth_users",
                     "expected a mapping of user names to bcrypt hashes");
    expect_web_error(alice + "  \"bad user\": " + alice_hash + "\n", 3, "basic_auth_users.bad user",
                     "is not a user name");
    expect_web_error(alice + "http_server_config:\n  headers:\n    Set-Cookie: a=b\n", 5,
                     "http_server_config.headers.Set-Cookie", "not a header the web configuration");
    expect_web_error(alice + "http_server_config:\n  http2: true\n", 4, "http_server_config.http2",
                     "HTTP/1.1 only");
    expect_web_error(alice + "- a\n", 3, "", "YAML syntax error");
    expect_web_error("[1, 2]\n", 1, "", "expected a mapping");

    const TlsFiles tls;
    const std::string pair = "tls_server_config:\n  cert_file: " + tls.certificate.path() +
                             "\n  key_file: " + tls.key.path() + "\n";
    expect_web_error(pair + "  cipher_suites: [TLS_AES_128_GCM_SHA256]\n", 4,
                     "tls_server_config.cipher_suites", "does not implement this key");
    expect_web_error(pair + "  client_auth_type: RequireAndVerifyClientCert\n", 4,
                     "tls_server_config.client_auth_type", "client_ca_file, which is missing");
    expect_web_error(pair + "  client_auth_type: Always\n", 4, "tls_server_config.client_auth_type",
                     "'Always' is not allowed");
    expect_web_error(pair + "  min_version: TLS13\n  max_version: TLS12\n", 5,
                     "tls_server_config.max_version", "is below min_version");
    expect_web_error(pair + "  min_version: TLS10\n", 4, "tls_server_config.min_version",
                     "'TLS10' is not allowed");
    expect_web_error("tls_server_config:\n  cert_file: " + tls.certificate.path() + "\n", 2,
                     "tls_server_config.key_file", "missing");
    expect_web_error(
        "tls_server_config:\n  cert_file: nonexistent.pem\n  key_file: " + tls.key.path() + "\n", 2,
        "tls_server_config.cert_file", "nonexistent.pem: No such file");
    const TempFile other_key(test::tls_fixtures::other_key, owner_only);
    expect_web_error("tls_server_config:\n  cert_file: " + tls.certificate.path() +
                         "\n  key_file: " + other_key.path() + "\n",
                     3, "tls_server_config.key_file", "is not the key of the certificate");
}

// It holds the hashes and names who may write: a file that grants rights (§5.6), and a secret.
TEST(GatewayConfigErrors, TheWebConfigurationIsAFileThatGrantsRights) {
    const std::string alice = std::string("basic_auth_users: { alice: ") + alice_hash + " }\n";
    for (const auto& [mode, fragment] :
         {std::pair{owner_only | perms::others_write, "is writable by every user"},
          std::pair{owner_only | perms::group_write, "is writable by its group"},
          std::pair{owner_only | perms::others_read, "readable by every user"}}) {
        SCOPED_TRACE(fragment);
        const WebFiles files(alice, mode);
        const auto errors = web_errors(files);
        ASSERT_EQ(errors.size(), 1u) << describe(errors);
        EXPECT_EQ(errors[0].file, files.web->path());
        EXPECT_NE(errors[0].message.find(fragment), std::string::npos) << to_string(errors[0]);
    }
    const auto missing = parse("http:\n  web_config_file: /nonexistent/web.yml\n" + hub);
    ASSERT_FALSE(missing);
    EXPECT_EQ(missing.error()[0].file, "/nonexistent/web.yml");
    EXPECT_NE(missing.error()[0].message.find("No such file"), std::string::npos);
}

TEST(GatewayConfigErrors, OperatorsAreUsersOfTheWebConfiguration) {
    expect_one_error({"http:\n  operators: [alice]\n" + hub, 2, "http.operators",
                      "there are none without http.web_config_file"});
    const WebFiles files(std::string("basic_auth_users: { alice: ") + alice_hash + " }\n");
    const auto errors = web_errors(files, "[alice, mallory]");
    ASSERT_EQ(errors.size(), 1u) << describe(errors);
    EXPECT_EQ(errors[0].file, "test.yaml");
    EXPECT_EQ(errors[0].line, 3);
    EXPECT_EQ(errors[0].key, "http.operators");
    EXPECT_NE(
        errors[0].message.find("'mallory' is not one of basic_auth_users in " + files.web->path()),
        std::string::npos)
        << to_string(errors[0]);
    const auto bad = web_errors(files, "[\"al ice\"]");
    ASSERT_EQ(bad.size(), 1u) << describe(bad);
    EXPECT_EQ(bad[0].key, "http.operators[0]");
    // Without passwords, a verified certificate's CN is the user: any name may be an operator.
    const TlsFiles tls;
    const WebFiles certificates("tls_server_config:\n  cert_file: " + tls.certificate.path() +
                                "\n  key_file: " + tls.key.path() +
                                "\n  client_ca_file: " + tls.ca.path() +
                                "\n  client_auth_type: RequireAndVerifyClientCert\n");
    EXPECT_TRUE(web_errors(certificates, "[\"scada-1\"]").empty());
    // The main file's errors come first, then the web file's.
    const WebFiles broken("basic_auth_users: { alice: secret }\n");
    const auto both =
        parse("http:\n  web_config_file: " + broken.web->path() + "\n  port: 1\n" + hub);
    ASSERT_FALSE(both);
    ASSERT_EQ(both.error().size(), 2u) << describe(both.error());
    EXPECT_EQ(both.error()[0].file, "test.yaml");
    EXPECT_EQ(both.error()[1].file, broken.web->path());
}

}  // namespace ioport::config
