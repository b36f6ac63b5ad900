// Plain MQTT with JSON and Home Assistant discovery (gateway.md §6.3) as pure functions: the
// topics, a module's retained state document, a `set` as the write it asks for, and the
// discovery configs of a module. No I/O: the daemon's JSON output owns the connection.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "protocol/error.hpp"
#include "protocol/gateway_map.hpp"
#include "protocol/ioport.hpp"
#include "protocol/points.hpp"
#include "protocol/tags.hpp"

namespace ioport::mqtt_json {

std::string status_topic(std::string_view prefix);  // <prefix>/status
// <prefix>/<link>/<module>/<leaf>: leaf "state", "availability", or "<point>/set".
std::string module_topic(std::string_view prefix, std::string_view link,
                         std::optional<ModuleAddress> module, std::string_view leaf);
std::string set_subscription(std::string_view prefix);  // <prefix>/+/+/+/set

// Of a topic prefix: room beside it for link, module, point and "set".
inline constexpr std::size_t max_topic_prefix = 128;
// A topic_prefix or discovery_prefix: 1..128 bytes of UTF-8 without control characters, levels
// that are not empty ("a//b", "/a", "a/"), no wildcard ('+', '#') and no leading '$' (brokers
// keep $-topics to themselves). The error says which rule the text breaks.
Result<> check_topic_prefix(std::string_view prefix);

struct SetTopic {
    std::string link;
    std::string module;  // as gateway::module_id() writes it
    std::string point;
    friend bool operator==(const SetTopic&, const SetTopic&) = default;
};
// nullopt for a topic that is not <prefix>/<link>/<module>/<point>/set.
std::optional<SetTopic> parse_set_topic(std::string_view prefix, std::string_view topic);

// The state keys of a module in document order: its points (protocol/points.hpp) but the ID-2's
// reset, a command: dim16/lim16 in0…in15 and word; dom16 out0…out15 and word; analog raw0…,
// value0…; rgbdm colour; mux8m pos, neg; the ID-2 stop, count.
std::vector<std::string> state_keys(std::optional<ModuleType> type);

// The retained state document of a module's point values (gateway::point_values, in the points'
// order): every key, null where nothing was read yet (so that a template never meets a missing
// key). Inputs and outputs are true/false, words and raw values numbers, value<ch> the
// engineering value (gateway.md §6.1), colour its name.
std::string state_json(std::optional<ModuleType> type,
                       std::span<const std::optional<gateway::PointValue>> values);

// --- Home Assistant discovery -------------------------------------------------------------

// What every discovery config of this gateway shares.
struct Node {
    std::string discovery_prefix;  // "homeassistant"
    std::string topic_prefix;      // "ioportd/box7"
    std::string version;           // ioportd's, for the device and origin blocks
};

// An id Home Assistant takes in topics and unique ids: letters, digits, _ and - as they are,
// anything else as _ ("ioportd/box7" → "ioportd_box7", the link "hub.0" → "hub_0"). Two texts
// can give the same: the configuration refuses two links that do.
std::string safe_id(std::string_view text);
// The topic prefix as such an id.
std::string node_id(std::string_view topic_prefix);

// Home Assistant's sensor device class for a unit, where it spells the unit exactly so
// ("°C" → temperature, "bar" → pressure, "A" → current, "V" → voltage); "" otherwise, as a
// class with a unit it does not accept makes Home Assistant refuse the whole config.
std::string_view device_class(std::string_view unit);

struct Discovery {
    std::string topic;    // <discovery_prefix>/<component>/<node>/<object>/config
    std::string payload;  // the JSON config; "" clears it (retained)
    friend bool operator==(const Discovery&, const Discovery&) = default;
};

// The gateway's own device: a binary sensor of its connectivity on <prefix>/status.
Discovery gateway_discovery(const Node& node);
// One entity per point of a module, in one Home Assistant device named as §6.1 names the
// module, routed via the gateway's device.
std::vector<Discovery> module_discovery(const Node& node, std::string_view link,
                                        std::optional<ModuleAddress> module,
                                        const gateway::ModuleTags& tags);

}  // namespace ioport::mqtt_json
