// The loader's inside (internal to config/; gateway_config.hpp is the API): the walk of the YAML
// tree and the Loader, which reads a file into a GatewayConfig and collects every error on the
// way. Its read_* methods live in the file of their section (modbus_section.cpp, links_section.cpp,
// ...), as the class lists them below: a key added to one section is added in one file.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <filesystem>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <yaml-cpp/yaml.h>

#include "config/gateway_config.hpp"
#include "config/parsers.hpp"

namespace ioport::config::detail {

// --- Walking the tree -----------------------------------------------------------------------

// yaml-cpp's lines are 0-based and -1 where unknown: this gives 1-based, 0 for unknown.
inline int line_of(const YAML::Node& node) {
    return node.Mark().line + 1;
}

inline std::string_view kind(const YAML::Node& node) {
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

constexpr int max_unit_id = 247;  // Modbus: 248..255 are reserved

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
        // A file the main one names (http.web_config_file) after it.
        std::ranges::stable_sort(errors_, {}, [&](const ConfigError& e) {
            return std::pair(e.file != config.file, e.line);
        });
        return Unexpected(std::move(errors_));
    }

  private:
    // loader.cpp: the walk of the tree, the top level, what more than one section reads.
    Fields fields(const YAML::Node& map, std::string path, Keys allowed);
    std::optional<Fields> mapping(const Entry& entry, std::string path, Keys allowed,
                                  std::string_view example);
    template <class T, class Parse>
    bool read(const Fields& fields, std::string_view name, std::string_view expected, T& out,
              Parse parse);
    void require(const Fields& fields, std::string_view name, std::string_view help);
    void read_allow(const Fields& fields, std::vector<Network>& allow);
    template <class T, class Parse>
    void read_list(const Fields& fields, std::string_view name, std::string_view list_example,
                   std::string_view item_example, Parse parse, std::vector<T>& items);
    void read_root(const YAML::Node& root, GatewayConfig& config);

    // modbus_section.cpp
    void read_modbus(const Entry& entry, ModbusSettings& modbus);

    // tls_section.cpp: modbus.tls and its roles.
    void read_tls(const Entry& entry, std::optional<TlsSettings>& tls);
    void read_tls_files(const Fields& fields, TlsSettings& tls);
    void read_roles(const Fields& fields, TlsSettings& tls);
    std::optional<modbus_security::Role> read_role(const Entry& entry, const std::string& path);
    void read_role_units(const Entry& entry, const std::string& path, modbus_security::Role& role);
    void check_role_units(const GatewayConfig& config);

    // http_section.cpp
    void read_http(const Entry& entry, std::optional<HttpSettings>& http);
    void read_server_names(const Fields& fields, std::vector<std::string>& names);
    void read_web(const Fields& fields, HttpSettings& http);

    // web_config.cpp: http.web_config_file, the exporter-toolkit's web configuration. Its errors
    // name its own file.
    std::optional<WebConfig> read_web_config(const std::string& path);
    void refuse_unimplemented(const Fields& fields);
    void read_web_tls(const Entry& entry, const std::filesystem::path& base,
                      std::optional<WebTlsSettings>& tls);
    void read_web_headers(const Entry& entry, WebConfig& web);
    void read_web_users(const Entry& entry, WebConfig& web);

    // mqtt_section.cpp: Sparkplug's mqtt:, and the connection keys mqtt_json: shares.
    void read_mqtt(const Entry& entry, std::optional<MqttSettings>& mqtt);
    // The keys of an MQTT connection, shared by mqtt: and mqtt_json: (client_id is the
    // section's own: its default differs).
    void read_connection(const Fields& fields, MqttSettings& connection);
    void read_brokers(const Fields& fields, MqttSettings& mqtt);
    void read_store(const Entry& entry, std::optional<StoreSettings>& store);
    void check_sparkplug_ids(const GatewayConfig& config);

    // mqtt_json_section.cpp
    void read_mqtt_json(const Entry& entry, std::optional<MqttJsonSettings>& mqtt_json);
    void check_topic_levels(const GatewayConfig& config);
    void check_client_ids(const GatewayConfig& config);

    // links_section.cpp: the links, their modules and identity, what must be unique.
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
    void check_unique(const Fields& fields, const LinkConfig& link, bool unit_id_valid);

    // tags_section.cpp: the names, units and scales of a module's channels and points.
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

}  // namespace ioport::config::detail
