// Sparkplug B 3.0 as pure functions (gateway.md §5.5): topics, the metrics each module publishes
// and their values, payloads to and from the protobuf wire format (sparkplug_b.proto), and the
// validation of a command (DCMD) into the gateway's own write. No I/O and no protobuf types in
// this interface: the edge node (daemon/sparkplug_node) and the tests use plain values.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "protocol/error.hpp"
#include "protocol/gateway_map.hpp"
#include "protocol/ioport.hpp"
#include "protocol/points.hpp"
#include "protocol/tags.hpp"

namespace ioport::sparkplug {

inline constexpr std::string_view namespace_prefix = "spBv1.0";

// --- Topics ---------------------------------------------------------------------------------

enum class MessageType { nbirth, ndeath, dbirth, ddeath, ndata, ddata, ncmd, dcmd, state };
std::string_view to_string(MessageType type);  // "NBIRTH", …, "STATE"

// spBv1.0/<group>/<type>/<node>[/<device>]; STATE is spBv1.0/STATE/<host id>.
std::string topic(std::string_view group, MessageType type, std::string_view node,
                  std::string_view device = {});
std::string state_topic(std::string_view host_id);

struct Topic {
    MessageType type = MessageType::ndata;
    std::string group;   // empty for STATE
    std::string node;    // the host id for STATE
    std::string device;  // empty for node messages
    friend bool operator==(const Topic&, const Topic&) = default;
};
// nullopt for a topic outside the namespace or not of this form.
std::optional<Topic> parse_topic(std::string_view topic);

// A group, edge node or device id: not empty, no '/', '+' or '#' (MQTT topic syntax), UTF-8
// without control characters. The message says what is wrong.
Result<> check_id(std::string_view id);

// --- Values and payloads ----------------------------------------------------------------------

// The data types ioportd publishes and accepts (Sparkplug 3.0 §6.4.16 numbering).
enum class DataType : std::uint32_t {
    int64 = 4,
    uint8 = 5,
    uint16 = 6,
    uint64 = 8,
    float32 = 9,
    boolean = 11,
    string = 12,
};
std::string_view to_string(DataType type);  // "UInt16", …

// A metric value: Boolean as bool; UInt8, UInt16, UInt64 and Int64 as their integer (Int64 as
// its two's complement bits); Float as float; String as string.
using Value = std::variant<bool, std::uint64_t, float, std::string>;

// A metric property (Sparkplug 3.0 §6.4.18): a Double (10) or a String (12). ioportd sends the
// tag properties Ignition's MQTT Engine applies: engUnit, engLow, engHigh, documentation.
struct Property {
    std::string key;
    std::variant<double, std::string> value;
    friend bool operator==(const Property&, const Property&) = default;
};

struct Metric {
    std::string name;  // empty when the metric goes by its alias alone (DATA after a BIRTH)
    std::optional<std::uint64_t> alias;
    std::optional<std::uint64_t> timestamp;  // ms since the Unix epoch
    // The type on the wire. A decoded metric of a type outside DataType keeps its number here
    // and no value.
    std::uint32_t datatype = 0;
    std::optional<Value> value;  // nullopt: is_null
    bool is_historical = false;  // a value from the store (gateway.md §6.2), not a current one
    std::vector<Property> properties{};  // births only: names, units and ranges (§6.1)
    friend bool operator==(const Metric&, const Metric&) = default;
};

struct Payload {
    std::uint64_t timestamp = 0;       // ms since the Unix epoch
    std::optional<std::uint64_t> seq;  // absent in NDEATH
    std::vector<Metric> metrics;
    friend bool operator==(const Payload&, const Payload&) = default;
};

// Sparkplug 3.0 §6.4.4: a birth gives every metric's datatype, and DATA SHOULD NOT repeat it
// (payloads-metric-datatype-not-req): the host knows it from the birth, by alias or name.
enum class Datatypes { sent, left_out };
std::vector<std::uint8_t> encode(const Payload& payload, Datatypes datatypes = Datatypes::sent);
// Fails with malformed for bytes that are not a Sparkplug B payload.
Result<Payload> decode(std::span<const std::uint8_t> bytes);

// A DDATA kept while no session could publish it (gateway.md §6.2): the device and the payload
// as it would have gone out, without seq (given when it is forwarded), its metrics by name (aliases
// belong to a session) with their acquisition timestamps. The body of a store record
// (protocol/store_segment.hpp): a version byte (1), the device id's length (2 bytes,
// little-endian) and bytes, then the encoded payload.
struct StoredData {
    std::string device;
    Payload payload;
    friend bool operator==(const StoredData&, const StoredData&) = default;
};
std::vector<std::uint8_t> encode_stored(const StoredData& data);
// Fails with malformed for bytes that are not such a body.
Result<StoredData> decode_stored(std::span<const std::uint8_t> bytes);

// STATE (Sparkplug 3.0 §7.2): {"online": true|false, "timestamp": <ms>}, read as JSON (other
// members are ignored). Fails, saying why, for anything else: invalid_argument, unread, beyond
// max_state_bytes (a STATE is a few dozen bytes; more is an attack on the reader), malformed
// when it is not such an object. A missing timestamp is 0 (older than any other).
inline constexpr std::size_t max_state_bytes = 1024;
struct HostState {
    bool online = false;
    std::uint64_t timestamp = 0;
    friend bool operator==(const HostState&, const HostState&) = default;
};
Result<HostState> parse_state(std::string_view json);
std::string state_json(bool online, std::uint64_t timestamp);

// --- The metrics of a module (gateway.md §5.5) ------------------------------------------------

// One Sparkplug device per module: "<link>.<type>.<number>", "<link>.id2" for the ID-2.
std::string device_id(std::string_view link, std::optional<ModuleAddress> module);

struct MetricSpec {
    std::string name;
    DataType type;
    bool writable = false;
    friend bool operator==(const MetricSpec&, const MetricSpec&) = default;
};
// Every metric a module will ever publish, in DBIRTH order: its points (protocol/points.hpp),
// each under Sparkplug's name for it (out3 is out/3, value0 value/0; words stay as they are),
// with its datatype. nullopt: the ID-2.
std::vector<MetricSpec> module_metrics(std::optional<ModuleType> type);
// A point's value as a metric's.
Value metric_value(const gateway::PointValue& value);

// The properties of module_metrics(type)'s metrics in a DBIRTH, in the same order (gateway.md
// §6.1): every value/<ch> has engLow and engHigh (its range) and engUnit when it has a unit; any
// metric of a named channel or point, or of a named module, has documentation ("boiler 1: supply
// temperature"). Metric names never change, so a rename never breaks a host's history.
std::vector<std::vector<Property>> module_properties(std::optional<ModuleAddress> module,
                                                     const gateway::ModuleTags& tags);

// --- Commands (DCMD) --------------------------------------------------------------------------

// How many metrics a command to this device may name: its writable ones (a host sets each at most
// once per command). nullopt: the ID-2.
std::size_t writable_metrics(std::optional<ModuleType> type);

// A command's bytes per metric it may name, and for the payload around them: a real command's
// metric (name, alias, timestamp, datatype, value) is some 30 bytes; the rest is room for long
// names and properties a host may add.
inline constexpr std::size_t command_bytes_per_metric = 1024;
// The longest command payload that may name `metrics` metrics: (metrics + 1) KiB.
constexpr std::size_t max_command_bytes(std::size_t metrics) {
    return (metrics + 1) * command_bytes_per_metric;
}

// The metrics a payload names (its top-level field 2, as decode sees them), counted by walking
// the protobuf fields without decoding any: no allocation, and cheap for any size. Fails with
// malformed for bytes that are not a sequence of protobuf fields.
Result<std::size_t> count_metrics(std::span<const std::uint8_t> bytes);

// A command's payload, decoded only when it is at most max_command_bytes(max_metrics) long and
// names at most `max_metrics` metrics (gateway.md §5.5: a DCMD naming more metrics than the device
// has writable ones is refused whole). Otherwise invalid_argument, saying how many it named and
// how many the device takes, before anything is decoded; malformed for bytes that are not a
// Sparkplug B payload.
Result<Payload> decode_command(std::span<const std::uint8_t> bytes, std::size_t max_metrics);

// A DCMD metric as a write of its point, planned by the one planner of every output
// (gateway::plan_point_write): output changes (dom16 bits or word, rgbdm colour, mux8m pos or
// neg, merged into the desired state when sent) or an ID-2 counter reset. `datatype`: what the
// command declares (0: none). Fails (invalid_argument, with a message naming the metric) for a
// metric the module does not have, one that is not writable, a declared datatype other than the
// metric's, a value of another kind or outside the metric's range: never truncated.
Result<gateway::WritePlan> plan_command(std::optional<ModuleAddress> module, std::string_view name,
                                        std::uint32_t datatype, const std::optional<Value>& value);

}  // namespace ioport::sparkplug
