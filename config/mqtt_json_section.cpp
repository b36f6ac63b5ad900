#include "config/loader.hpp"

#include "protocol/mqtt_id.hpp"
#include "protocol/mqtt_json.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 12> mqtt_json_keys{
    "broker",    "brokers",  "client_id",    "username",  "password_file",    "ca_file",
    "keepalive", "protocol", "topic_prefix", "discovery", "discovery_prefix", "deadband"};

}  // namespace

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

}  // namespace ioport::config::detail
