// Fuzz target: the YAML configuration loader, on any text an operator (or an editor gone wrong)
// might save as ioportd.yaml.
//
// Input: the file's text. parse_config() must return, never throw or crash. When it fails,
// every error names the file and a line of it, in line order. When it succeeds, the
// configuration keeps every rule of gateway.md §1 and §4 (checked here independently of the
// loader), and --print-map's rows and formats can be made from it.
#include <arpa/inet.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <set>
#include <string>
#include <string_view>

#include "config/duration.hpp"
#include "config/gateway_config.hpp"
#include "fuzz/fuzz.hpp"
#include "protocol/gateway_map.hpp"

namespace ioport::fuzz {
namespace {

using namespace std::chrono_literals;
using config::GatewayConfig;
using config::Protocol;

constexpr std::string_view file_name = "fuzz.yaml";

// No file system: two spellings of one port, as a by-id symlink and the node it points to.
std::string resolve(const std::string& device) {
    constexpr std::string_view by_id = "/dev/serial/by-id/";
    if (device.starts_with(by_id)) return "/dev/" + device.substr(by_id.size());
    return device;
}

bool is_ip(const std::string& text) {
    std::array<std::uint8_t, 16> bytes{};
    return inet_pton(AF_INET, text.c_str(), bytes.data()) == 1 ||
           inet_pton(AF_INET6, text.c_str(), bytes.data()) == 1;
}

// Durations are written back in messages and summaries; they must read back the same.
void check_duration(std::chrono::microseconds duration) {
    const auto again = parse_duration(format_duration(duration));
    check(again.has_value() && *again == duration, "a duration formats to text that parses back");
}

// A TLS section is only there when its files were read and checked, and its roles name units.
void check_tls(const config::TlsSettings& tls) {
    check(is_ip(tls.listen_host), "tls.listen is an IP address");
    check(!tls.certificate_pem.empty() && !tls.key_pem.empty() && !tls.client_ca_pem.empty(),
          "the TLS files were read");
    check(!tls.roles.empty(), "at least one role");
    check(tls.default_role.empty() || tls.roles.contains(tls.default_role),
          "default_role is a role");
    for (const auto& [name, role] : tls.roles)
        check(!name.empty() && role.units.any() && !role.units.test(0) &&
                  (role.units.all() || !role.units.test(255)),
              "a role has a name and units 1..247, or all");
}

void check_modbus(const config::ModbusSettings& modbus) {
    check(modbus.plain() ? is_ip(modbus.listen_host) : modbus.listen_port == 0,
          "listen is an IP address, or off");
    if (modbus.tls) check_tls(*modbus.tls);
    check(modbus.max_connections >= 1 && modbus.max_connections <= 65535, "max_connections");
    check(modbus.idle_timeout >= 0us, "idle_timeout");
    check(modbus.keepalive >= 0us && modbus.keepalive <= 2h, "keepalive");
    check_duration(modbus.idle_timeout);
    check_duration(modbus.keepalive);
    for (const auto& network : modbus.allow) {
        const auto bytes = network.network.address().to_bytes();
        const std::size_t prefix = network.network.prefix_length();
        check(prefix <= 128 && network.network.address().scope_id() == 0, "prefix length, no zone");
        // An IPv4 network is held as ::ffff:a.b.c.d/(96 + n).
        std::array<std::uint8_t, 4> v4{};
        const auto written = network.text.substr(0, network.text.find('/'));
        if (inet_pton(AF_INET, written.c_str(), v4.data()) == 1)
            check(network.network.address().is_v4_mapped() && prefix >= 96 &&
                      std::equal(v4.begin(), v4.end(), bytes.begin() + 12),
                  "an IPv4 network is IPv4-mapped");
        // CIDR: no bit set after the prefix (the loader says "did you mean …" otherwise).
        for (auto bit = prefix; bit < 128; ++bit)
            check((bytes[bit / 8] >> (7 - bit % 8) & 1U) == 0, "no host bits");
        check(config::contains(network, network.network.address()), "a network contains itself");
    }
}

// Names, units and scales (gateway.md §6.1): resolved, printable, and values a float32 holds.
void check_tags(const config::ModuleConfig& module) {
    const auto type = module.address.type;
    const auto& tags = module.tags;
    const auto text = [](const std::string& t, bool may_be_empty) {
        return gateway::check_tag_text(t, may_be_empty).has_value();
    };
    check(text(tags.name, false), "a module name is 1..64 bytes of UTF-8, no control character");
    const auto channels =
        gateway::has_channels(type) ? static_cast<std::size_t>(reply_words(type)) : 0U;
    check(tags.channels.size() == channels, "an analog module has a tag per channel, others none");
    for (const auto& channel : tags.channels) {
        check(channel.name.empty() || text(channel.name, false), "a channel name is printable");
        check(text(channel.unit, true), "a unit is printable");
        check(std::isfinite(channel.range[0]) && std::isfinite(channel.range[1]) &&
                  channel.range[0] < channel.range[1],
              "a range is finite, lo < hi");
        if (const auto& scale = channel.scale) {
            check(scale->in_lo != scale->in_hi && scale->out_lo != scale->out_hi,
                  "a scale maps a span onto a span");
            for (const std::uint16_t raw : {std::uint16_t{0}, std::uint16_t{0xFFFF}})
                check(std::isfinite(gateway::channel_value(type, raw, scale)),
                      "a scaled value fits a float32");
        }
    }
    for (const auto& point : tags.points)
        check(point.empty() || (gateway::has_points(type) && text(point, false)),
              "points are named only where the module has them, and printably");
}

void check_link(const config::LinkConfig& link) {
    check(!link.name.empty() && !link.device.empty(), "a link has a name and a device");
    check(link.unit_id >= 1 && link.unit_id <= 247, "unit_id 1..247");
    check(link.timeout >= 1ms && link.timeout <= 10s, "timeout 1ms..10s");
    check(link.retries >= 0 && link.retries <= 10, "retries 0..10");
    check_duration(link.timeout);
    if (link.protocol == Protocol::id2) {
        check(link.baud == 9600, "an id2 link runs at 9600 baud");
        check(link.modules.empty(), "an id2 link has no modules");
        return;
    }
    check(link.baud == 38400 || link.baud == 115200, "an ioport link runs at 38400 or 115200");
    check(!link.modules.empty(), "an ioport link has a module");
    std::set<int> slots;
    std::set<std::string> names;
    for (const auto& module : link.modules) {
        check(module.address.number < modules_per_type, "module number 0..7");
        check(names.insert(module.tags.name).second, "module names are unique per link");
        check_tags(module);
        check(slots.insert(slot(module.address)).second, "a module is configured once per link");
        if (is_output(module.address.type)) {
            check(validate_output_value(module.address.type, module.initial).has_value(),
                  "initial is a value the module can be commanded");
            check(module.refresh >= 10ms, "refresh at least 10ms");
            check(module.poll == 0us, "an output module is not polled");
            check_duration(module.refresh);
        } else {
            check(module.initial == 0 && module.refresh == 1s, "an input module has no output");
            check(module.poll >= 0us, "poll");
            check_duration(module.poll);
        }
    }
}

// --print-map, as ioportd's main() makes it.
void check_map(const config::LinkConfig& link) {
    gateway::UnitMap unit{
        link.protocol == Protocol::id2 ? gateway::UnitKind::id2 : gateway::UnitKind::ioport,
        link.unit_id,
        link.name,
        {}};
    for (const auto& module : link.modules) {
        unit.modules.push_back(module.address);
        unit.tags.push_back(module.tags);
    }
    const auto rows = gateway::map_rows(unit);
    check(!rows.empty(), "every unit has rows, its diagnostics at least");
    check(std::is_sorted(rows.begin(), rows.end(),
                         [](const gateway::MapRow& a, const gateway::MapRow& b) {
                             return std::pair{a.table, a.address} < std::pair{b.table, b.address};
                         }),
          "rows are in table and address order");
    const auto csv = gateway::format_csv(rows);
    const auto markdown = gateway::format_markdown(rows);
    // Link names are free text: quotes, commas and line breaks in them must stay inside a field.
    check(csv.ends_with("\r\n") && markdown.ends_with("|\n"), "the formats end their last line");
}

void check_config(const GatewayConfig& config) {
    check(config.file == file_name, "the configuration names its file");
    check(!config.links.empty(), "at least one link");
    check_modbus(config.modbus);
    std::set<std::string> names;
    std::set<std::string> devices;
    std::set<int> unit_ids;
    for (const auto& link : config.links) {
        check_link(link);
        check(names.insert(link.name).second, "link names are unique");
        check(devices.insert(resolve(link.device)).second, "devices are unique once resolved");
        check(unit_ids.insert(link.unit_id).second, "unit ids are unique");
        check_map(link);
    }
}

void check_errors(const std::vector<config::ConfigError>& errors, std::string_view text) {
    check(!errors.empty(), "a failure says why");
    const auto lines = static_cast<int>(std::count(text.begin(), text.end(), '\n')) + 1;
    for (const auto& error : errors) {
        check(error.file == file_name, "an error names the file");
        check(error.line >= 0 && error.line <= lines, "an error names a line of the file");
        check(!error.message.empty(), "an error says what is wrong");
        check(to_string(error).starts_with(file_name), "the message starts with the file");
    }
    check(std::is_sorted(errors.begin(), errors.end(),
                         [](const auto& a, const auto& b) { return a.line < b.line; }),
          "errors are in line order");
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string_view text(reinterpret_cast<const char*>(data), size);
    const auto loaded = ioport::config::parse_config(text, std::string(ioport::fuzz::file_name),
                                                     ioport::fuzz::resolve);
    if (loaded)
        ioport::fuzz::check_config(*loaded);
    else
        ioport::fuzz::check_errors(loaded.error(), text);
    return 0;
}
