#include "protocol/mqtt_json.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <utility>
#include <variant>

#include <fmt/format.h>

#include "protocol/json.hpp"
#include "protocol/json_reader.hpp"

namespace ioport::mqtt_json {
namespace {}  // namespace

std::string safe_id(std::string_view text) {
    std::string out(text);
    for (auto& c : out) {
        const bool kept = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') ||
                          (c >= '0' && c <= '9') || c == '_' || c == '-';
        if (!kept) c = '_';
    }
    return out;
}

namespace {

void json_value(Json& json, const std::optional<gateway::PointValue>& value, std::string_view key) {
    if (!value) {
        json.null();
        return;
    }
    if (key == "colour") {
        const auto code = std::get<std::uint64_t>(*value);
        if (code < colour_count)
            json.value(name(static_cast<Colour>(code)));
        else
            json.null();
        return;
    }
    std::visit([&](const auto& v) { json.value(v); }, *value);
}

}  // namespace

std::string status_topic(std::string_view prefix) {
    return fmt::format("{}/status", prefix);
}

std::string module_topic(std::string_view prefix, std::string_view link,
                         std::optional<ModuleAddress> module, std::string_view leaf) {
    return fmt::format("{}/{}/{}/{}", prefix, link, gateway::module_id(module), leaf);
}

std::string set_subscription(std::string_view prefix) {
    return fmt::format("{}/+/+/+/set", prefix);
}

Result<> check_topic_prefix(std::string_view prefix) {
    const auto bad = [](std::string message) {
        return fail(Errc::invalid_argument, std::move(message));
    };
    if (prefix.empty()) return bad("must not be empty");
    if (prefix.size() > max_topic_prefix)
        return bad(fmt::format("is {} bytes long: at most {}", prefix.size(), max_topic_prefix));
    if (prefix.front() == '$')
        return bad("starts with '$', which brokers keep for their own topics");
    if (prefix.front() == '/' || prefix.back() == '/' || prefix.find("//") != prefix.npos)
        return bad("has an empty topic level: no '/' at either end, none twice in a row");
    for (std::size_t at = 0; at < prefix.size();) {
        const auto length = utf8_sequence(prefix.substr(at));
        if (length == 0) return bad(fmt::format("is not valid UTF-8 at byte {}", at));
        const auto c = static_cast<unsigned char>(prefix[at]);
        if (c < 0x20 || c == 0x7F)
            return bad(fmt::format("has a control character at byte {}", at));
        if (c == '+' || c == '#')
            return bad(fmt::format("has '{}', an MQTT wildcard, at byte {}", prefix[at], at));
        at += length;
    }
    return {};
}

std::optional<SetTopic> parse_set_topic(std::string_view prefix, std::string_view topic) {
    if (!topic.starts_with(prefix) || topic.size() <= prefix.size() || topic[prefix.size()] != '/')
        return std::nullopt;
    topic.remove_prefix(prefix.size() + 1);
    std::array<std::string_view, 4> parts{};
    for (std::size_t i = 0; i < parts.size(); ++i) {
        const auto slash = topic.find('/');
        parts[i] = topic.substr(0, slash);
        if (parts[i].empty()) return std::nullopt;
        if (slash == std::string_view::npos) {
            if (i != parts.size() - 1) return std::nullopt;
            topic = {};
        } else {
            topic.remove_prefix(slash + 1);
        }
    }
    if (!topic.empty() || parts[3] != "set") return std::nullopt;
    return SetTopic{std::string(parts[0]), std::string(parts[1]), std::string(parts[2])};
}

std::vector<std::string> state_keys(std::optional<ModuleType> type) {
    std::vector<std::string> keys;
    for (const auto& point : gateway::module_points(type))
        if (!point.command) keys.push_back(point.id);
    return keys;
}

std::string state_json(std::optional<ModuleType> type,
                       std::span<const std::optional<gateway::PointValue>> values) {
    const auto& points = gateway::module_points(type);
    Json json;
    json.begin_object();
    for (std::size_t i = 0; i < points.size() && i < values.size(); ++i) {
        if (points[i].command) continue;  // a command, not a state
        json.key(points[i].id);
        json_value(json, values[i], points[i].id);
    }
    json.end_object();
    return json.take();
}

// --- Home Assistant discovery -------------------------------------------------------------

std::string node_id(std::string_view topic_prefix) {
    return safe_id(topic_prefix);
}

std::string_view device_class(std::string_view unit) {
    // Home Assistant's units per class (home-assistant.io, sensor#device-class), exact spelling.
    static constexpr std::array<std::pair<std::string_view, std::string_view>, 27> classes{{
        {"°C", "temperature"}, {"°F", "temperature"}, {"K", "temperature"}, {"Pa", "pressure"},
        {"kPa", "pressure"},   {"hPa", "pressure"},   {"bar", "pressure"},  {"cbar", "pressure"},
        {"mbar", "pressure"},  {"mmHg", "pressure"},  {"inHg", "pressure"}, {"psi", "pressure"},
        {"V", "voltage"},      {"mV", "voltage"},     {"µV", "voltage"},    {"kV", "voltage"},
        {"MV", "voltage"},     {"A", "current"},      {"mA", "current"},    {"W", "power"},
        {"kW", "power"},       {"MW", "power"},       {"Hz", "frequency"},  {"kHz", "frequency"},
        {"MHz", "frequency"},  {"GHz", "frequency"},  {"mHz", "frequency"},
    }};
    for (const auto& [symbol, device] : classes)
        if (symbol == unit) return device;
    return "";
}

namespace {

struct Entity {
    std::string_view component;  // binary_sensor, switch, sensor, select, number, button
    std::string point;           // state key, and the last part of the object id
    std::string name;
};

void common(Json& json, const Node& node, std::string_view object_id, const Entity& entity,
            std::string_view availability) {
    json.member("name", entity.name)
        .member("unique_id", fmt::format("{}_{}", node_id(node.topic_prefix), object_id))
        .key("availability")
        .begin_array()
        .begin_object()
        .member("topic", status_topic(node.topic_prefix))
        .end_object();
    if (!availability.empty()) json.begin_object().member("topic", availability).end_object();
    json.end_array().member("availability_mode", "all");
    json.key("origin")
        .begin_object()
        .member("name", "ioportd")
        .member("sw_version", node.version)
        .end_object();
}

std::string config_topic(const Node& node, std::string_view component, std::string_view object) {
    return fmt::format("{}/{}/{}/{}/config", node.discovery_prefix, component,
                       node_id(node.topic_prefix), object);
}

std::string point_name(const std::string& configured, std::string_view fallback) {
    return configured.empty() ? std::string(fallback) : configured;
}

// The entities of a module: one per point Home Assistant shows.
std::vector<Entity> entities(std::optional<ModuleAddress> module, const gateway::ModuleTags& tags) {
    std::vector<Entity> out;
    if (!module) {
        out.push_back({"binary_sensor", "stop", "stop"});
        out.push_back({"sensor", "count", "count"});
        out.push_back({"button", "reset", "reset count"});
        return out;
    }
    const auto type = module->type;
    const auto point = [&](std::size_t k) {
        return k < tags.points.size() ? tags.points[k] : std::string();
    };
    switch (type) {
        case ModuleType::dim16:
        case ModuleType::lim16:
            for (std::size_t k = 0; k < 16; ++k)
                out.push_back({"binary_sensor", fmt::format("in{}", k),
                               point_name(point(k), fmt::format("input {}", k))});
            break;
        case ModuleType::dom16:
            for (std::size_t k = 0; k < 16; ++k)
                out.push_back({"switch", fmt::format("out{}", k),
                               point_name(point(k), fmt::format("output {}", k))});
            break;
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            for (std::size_t c = 0; c < tags.channels.size(); ++c)
                out.push_back({"sensor", fmt::format("value{}", c),
                               point_name(tags.channels[c].name, tags.channels.size() > 1
                                                                     ? fmt::format("channel {}", c)
                                                                     : std::string("value"))});
            break;
        case ModuleType::rgbdm:
            out.push_back({"select", "colour", "colour"});
            break;
        case ModuleType::mux8m:
            out.push_back({"number", "pos", "pos"});
            out.push_back({"number", "neg", "neg"});
            break;
    }
    return out;
}

// Decimals Home Assistant shows: those the status page shows for the channel's range.
int display_precision(const std::array<double, 2>& range) {
    const double span = range[1] - range[0];
    return std::clamp(3 - static_cast<int>(std::floor(std::log10(span > 0 ? span : 1))), 0, 3);
}

void component_keys(Json& json, const Entity& entity, std::optional<ModuleAddress> module,
                    const gateway::ModuleTags& tags, const std::string& state,
                    const std::string& command) {
    const auto& key = entity.point;
    const auto on_off = fmt::format("{{{{ 'ON' if value_json.{} else 'OFF' }}}}", key);
    const auto plain = fmt::format("{{{{ value_json.{} }}}}", key);
    if (entity.component == "binary_sensor") {
        json.member("state_topic", state).member("value_template", on_off);
        if (!module) json.member("device_class", "problem");  // the machine-stop input
    } else if (entity.component == "switch") {
        json.member("state_topic", state)
            .member("value_template", on_off)
            .member("command_topic", command)
            .member("payload_on", "ON")
            .member("payload_off", "OFF")
            .member("optimistic", false);  // on only once the device confirmed it
    } else if (entity.component == "sensor" && !module) {
        json.member("state_topic", state)
            .member("value_template", plain)
            .member("state_class", "total_increasing");
    } else if (entity.component == "sensor") {
        const auto channel = static_cast<std::size_t>(std::stoul(key.substr(5)));
        const auto& tag = tags.channels.at(channel);
        json.member("state_topic", state)
            .member("value_template", plain)
            .member("state_class", "measurement")
            .member("suggested_display_precision", display_precision(tag.range));
        if (!tag.unit.empty()) json.member("unit_of_measurement", tag.unit);
        if (const auto device = device_class(tag.unit); !device.empty())
            json.member("device_class", device);
    } else if (entity.component == "select") {
        json.member("state_topic", state)
            .member("value_template", plain)
            .member("command_topic", command)
            .member("optimistic", false)
            .key("options")
            .begin_array();
        for (int c = 0; c < colour_count; ++c)
            json.value(name(static_cast<Colour>(c)));
        json.end_array();
    } else if (entity.component == "number") {
        json.member("state_topic", state)
            .member("value_template", plain)
            .member("command_topic", command)
            .member("command_template", "{{ value | int }}")
            .member("min", 0)
            .member("max", mux_test_points - 1)
            .member("step", 1)
            .member("mode", "box")
            .member("optimistic", false);
    } else if (entity.component == "button") {
        json.member("command_topic", command).member("payload_press", "ON");
    }
}

}  // namespace

std::string bridge_topic(std::string_view prefix, std::string_view leaf) {
    return fmt::format("{}/bridge/{}", prefix, leaf);
}

std::string bridge_request_subscription(std::string_view prefix) {
    return bridge_topic(prefix, "request/+");
}

std::optional<std::string> parse_bridge_request(std::string_view prefix, std::string_view topic) {
    const auto head = bridge_topic(prefix, "request/");
    if (!topic.starts_with(head)) return std::nullopt;
    const auto name = topic.substr(head.size());
    if (name.empty() || name.find('/') != std::string_view::npos) return std::nullopt;
    return std::string(name);
}

std::string bridge_info_json(std::string_view version, std::span<const BridgeLink> links,
                             bool discovery, bool read_only) {
    Json json;
    json.begin_object().member("version", version).key("links").begin_array();
    for (const auto& link : links) {
        json.begin_object()
            .member("name", link.name)
            .member("protocol", link.protocol)
            .member("unit_id", link.unit_id)
            .key("modules")
            .begin_array();
        for (const auto& module : link.modules)
            json.begin_object()
                .member("id", module.id)
                .member("type", module.type)
                .member("name", module.name)
                .member("status", module.status)
                .end_object();
        json.end_array().end_object();
    }
    json.end_array().member("discovery", discovery).member("read_only", read_only).end_object();
    return json.take();
}

BridgeRequest parse_bridge_request_payload(std::string_view payload) {
    const auto object = JsonObject::parse(payload);
    if (!object)
        return {std::nullopt, fmt::format("the payload is {}: send a JSON object, {{}} "
                                          "at least",
                                          object.error().message)};
    if (!object->has("transaction")) return {};
    const auto text = object->string("transaction");
    const bool scalar = text || object->scalar_text("transaction");
    if (!scalar || (text && text->size() > max_transaction_bytes))
        return {std::nullopt, fmt::format("transaction: a string of at most {} bytes, a number "
                                          "or a boolean",
                                          max_transaction_bytes)};
    return {object->json("transaction"), {}};
}

std::string bridge_response_json(std::string_view data_json, std::string_view error,
                                 const std::optional<std::string>& transaction) {
    Json json;
    json.begin_object().member("status", error.empty() ? "ok" : "error");
    json.key("data").raw(error.empty() ? data_json : "{}");
    if (!error.empty()) json.member("error", error);
    if (transaction) json.key("transaction").raw(*transaction);
    json.end_object();
    return json.take();
}

std::string health_json(std::span<const std::pair<std::string, std::string>> links) {
    const bool healthy =
        std::ranges::all_of(links, [](const auto& link) { return link.second == "ok"; });
    Json json;
    json.begin_object().member("healthy", healthy).key("links").begin_object();
    for (const auto& [name, verdict] : links)
        json.member(name, verdict);
    json.end_object().end_object();
    return json.take();
}

Discovery gateway_discovery(const Node& node) {
    const auto id = node_id(node.topic_prefix);
    Json json;
    json.begin_object();
    json.member("name", "connection")
        .member("unique_id", fmt::format("{}_connection", id))
        .member("state_topic", status_topic(node.topic_prefix))
        .member("payload_on", "online")
        .member("payload_off", "offline")
        .member("device_class", "connectivity")
        .member("entity_category", "diagnostic");
    json.key("device")
        .begin_object()
        .key("identifiers")
        .begin_array()
        .value(id)
        .end_array()
        .member("name", fmt::format("ioportd {}", node.topic_prefix))
        .member("manufacturer", "ioportd")
        .member("model", "serial-to-Modbus gateway")
        .member("sw_version", node.version)
        .end_object();
    json.key("origin")
        .begin_object()
        .member("name", "ioportd")
        .member("sw_version", node.version)
        .end_object();
    json.end_object();
    return {config_topic(node, "binary_sensor", "connection"), json.take()};
}

Discovery link_discovery(const Node& node, std::string_view link) {
    const auto id = node_id(node.topic_prefix);
    const auto object = fmt::format("{}_connectivity", safe_id(link));
    Json json;
    json.begin_object();
    json.member("name", fmt::format("link {}", link))
        .member("unique_id", fmt::format("{}_{}", id, object))
        .member("state_topic",
                bridge_topic(node.topic_prefix, fmt::format("connectivity/{}", link)))
        .member("availability_topic", status_topic(node.topic_prefix))
        .member("device_class", "connectivity")
        .member("entity_category", "diagnostic");
    json.key("device").begin_object().key("identifiers").begin_array().value(id).end_array();
    json.end_object();
    json.key("origin")
        .begin_object()
        .member("name", "ioportd")
        .member("sw_version", node.version)
        .end_object();
    json.end_object();
    return {config_topic(node, "binary_sensor", object), json.take()};
}

std::vector<Discovery> module_discovery(const Node& node, std::string_view link,
                                        std::optional<ModuleAddress> module,
                                        const gateway::ModuleTags& tags) {
    const auto id = node_id(node.topic_prefix);
    const auto device_id = fmt::format("{}_{}", safe_id(link), gateway::module_id(module));
    const auto state = module_topic(node.topic_prefix, link, module, "state");
    const auto availability = module_topic(node.topic_prefix, link, module, "availability");
    std::vector<Discovery> out;
    for (const auto& entity : entities(module, tags)) {
        const auto object = fmt::format("{}_{}", device_id, entity.point);
        const auto command =
            module_topic(node.topic_prefix, link, module, fmt::format("{}/set", entity.point));
        Json json;
        json.begin_object();
        common(json, node, object, entity, availability);
        component_keys(json, entity, module, tags, state, command);
        json.key("device")
            .begin_object()
            .key("identifiers")
            .begin_array()
            .value(fmt::format("{}_{}", id, device_id))
            .end_array()
            .member("name", module ? tags.name : fmt::format("ID-2 {}", link))
            .member("manufacturer", "iomlogic")
            .member("model", module ? std::string(name(module->type)) : std::string("ID-2"))
            .member("via_device", id)
            .end_object();
        json.end_object();
        out.push_back({config_topic(node, entity.component, object), json.take()});
    }
    return out;
}

}  // namespace ioport::mqtt_json
