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

// --- The bridge topics (gateway.md §7.3, zigbee2mqtt's conventions) ----------------------

// <prefix>/bridge/<leaf>: "info", "request/<name>", "response/<name>", "connectivity/<link>".
// No module topic is one of them, whatever a link is named: a module topic's third level is a
// module id ("dim16_0", "id2").
std::string bridge_topic(std::string_view prefix, std::string_view leaf);
std::string bridge_request_subscription(std::string_view prefix);  // <prefix>/bridge/request/+
// The name of a request's topic <prefix>/bridge/request/<name>; nullopt for any other topic.
std::optional<std::string> parse_bridge_request(std::string_view prefix, std::string_view topic);

// bridge/info: what this gateway is, retained.
struct BridgeModule {
    std::string id;      // as gateway::module_id writes it
    std::string type;    // "dim16", …, "id2"
    std::string name;    // §6.1's name, else the id
    std::string status;  // "online", "no answer", … (the state API's status_text)
};
struct BridgeLink {
    std::string name;
    std::string protocol;  // "ioport" | "id2"
    int unit_id = 1;
    std::vector<BridgeModule> modules;
};
std::string bridge_info_json(std::string_view version, std::span<const BridgeLink> links,
                             bool discovery, bool read_only);

// The longest transaction echoed, as a string's bytes.
inline constexpr std::size_t max_transaction_bytes = 128;
// A request's payload: a JSON object, whose "transaction" (a string, number or boolean) is echoed
// in the response as the request gave it. Fails saying what is wrong; the transaction is kept
// where it could be read, so that even an error answer carries it.
struct BridgeRequest {
    std::optional<std::string> transaction;  // as JSON text
    std::string error;                       // "" when the payload is as it should be
};
BridgeRequest parse_bridge_request_payload(std::string_view payload);
// {"status": "ok", "data": <data>} or {"status": "error", "data": {}, "error": "…"}, with
// "transaction" when the request had one.
std::string bridge_response_json(std::string_view data_json, std::string_view error,
                                 const std::optional<std::string>& transaction);
// health_check's data: {"healthy": bool, "links": {<link>: "ok" | <reason>}}; healthy when every
// link's verdict is "ok" (gateway.md §5.4's /healthz).
std::string health_json(std::span<const std::pair<std::string, std::string>> links);

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
// On the gateway's device, a binary sensor per link: on while its port is open and every module
// online, from <prefix>/bridge/connectivity/<link> (ON or OFF, retained).
Discovery link_discovery(const Node& node, std::string_view link);
// One entity per point of a module, in one Home Assistant device named as §6.1 names the
// module, routed via the gateway's device.
std::vector<Discovery> module_discovery(const Node& node, std::string_view link,
                                        std::optional<ModuleAddress> module,
                                        const gateway::ModuleTags& tags);

}  // namespace ioport::mqtt_json
