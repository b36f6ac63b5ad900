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

struct Metric;

// A Template (Sparkplug 3.0 §6.4.14, datatype 19), the value of a metric: a definition (NBIRTH,
// is_definition, no template_ref) or an instance of one (template_ref names the definition).
// ioportd's templates have no parameters (gateway.md §7.2); decode skips a host's.
struct Template {
    std::string version;         // empty: absent
    std::string template_ref;    // empty: absent (a definition)
    bool is_definition = false;  // always on the wire (payloads-template-is-definition)
    std::vector<Metric> members;
    // Member by member, written out (sparkplug.cpp): Metric is incomplete here, and clang 14's
    // clang-tidy crashes on a defaulted comparison of the two types that hold each other.
    friend bool operator==(const Template&, const Template&);
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
    // Datatype Template (19): the definition or instance this metric is; `value` is then nullopt
    // and no is_null goes on the wire.
    std::optional<Template> template_value{};
    friend bool operator==(const Metric&, const Metric&) = default;
};

struct Payload {
    std::uint64_t timestamp = 0;       // ms since the Unix epoch
    std::optional<std::uint64_t> seq;  // absent in NDEATH
    std::vector<Metric> metrics;
    friend bool operator==(const Payload&, const Payload&) = default;
};

// Sparkplug 3.0 §6.4.4: a birth gives every metric's datatype, and DATA SHOULD NOT repeat it
// (payloads-metric-datatype-not-req): the host knows it from the birth, by alias or name, and a
// template member's from the definition. Left out for template members too.
enum class Datatypes { sent, left_out };
std::vector<std::uint8_t> encode(const Payload& payload, Datatypes datatypes = Datatypes::sent);
// Templates within templates deeper than this do not decode (ioportd's are one level deep; a
// host's command is bounded in bytes, and this bounds the recursion of reading it).
inline constexpr int max_template_depth = 4;
// Fails with malformed for bytes that are not a Sparkplug B payload, or nest templates deeper
// than max_template_depth.
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

// One Sparkplug device per module: "<link>.<type>.<number>", "<link>.id2" for the ID-2, with
// another `separator` where the configuration says so (a broker that rewrites the '.' of topics).
// Unique whatever the link names: the last part is a number or "id2", and no type's name holds
// a separator.
inline constexpr std::string_view device_id_separators = ".-_:";
std::string device_id(std::string_view link, std::optional<ModuleAddress> module,
                      char separator = '.');

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

// --- Templates (gateway.md §7.2, mqtt.templates) --------------------------------------------

// Datatype Template (Sparkplug 3.0 §6.4.16).
inline constexpr std::uint32_t template_datatype = 19;
// Every definition is version "1": members are never added or removed without a new version.
inline constexpr std::string_view template_version = "1";
// A module type's template, and its instance metric in DBIRTH and DDATA: "dim16", …, "id2"
// (nullopt: the ID-2).
std::string template_name(std::optional<ModuleType> type);
// Its definition metric in NBIRTH: "_types_/dim16", the folder Ignition's MQTT Engine keeps UDT
// definitions in.
std::string definition_name(std::optional<ModuleType> type);
// The NBIRTH metric defining a type's template: datatype Template, no value of its own, a
// Template with is_definition, version "1", no template_ref, and module_metrics(type) as members
// (names and datatypes, is_null: a definition carries no values).
Metric template_definition(std::optional<ModuleType> type, std::uint64_t timestamp);
// An instance of a type's template holding `members` (a DBIRTH's are every member, with values
// and properties; a DDATA's only those that changed, the caller clearing the name to go by the
// alias): named template_name(type), template_ref template_name(type), is_definition false.
Metric template_instance(std::optional<ModuleType> type, std::vector<Metric> members,
                         std::optional<std::uint64_t> alias, std::uint64_t timestamp);
// The flat metrics of a DDATA (by name) as the instance a template session sends, and back: the
// store keeps records flat (by name), so a record forwarded goes out in the form the session's
// births announced, whichever form it was made in. Flat metrics pass to_flat() unchanged; an
// instance's members come out under their names, with the instance's is_historical.
std::vector<Metric> to_flat(std::vector<Metric> metrics);

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
// The metrics a command asks to write, counted the same way: a metric whose value is a Template
// (field 18) counts as its member metrics (at least one), any other as one. For a payload without
// templates, count_metrics().
Result<std::size_t> count_command_metrics(std::span<const std::uint8_t> bytes);
// Of a decoded payload's metrics, counted as count_command_metrics counts them.
std::size_t command_metrics(const std::vector<Metric>& metrics);

// A command's payload, decoded only when it is at most max_command_bytes(max_metrics) long and
// names at most `max_metrics` metrics, an instance's members counted one by one
// (count_command_metrics; gateway.md §5.5: a DCMD naming more metrics than the device has
// writable ones is refused whole). Otherwise invalid_argument, saying how many it named and how
// many the device takes, before anything is decoded; malformed for bytes that are not a
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

// The writes a DCMD metric asks for (gateway.md §7.2): a flat metric is itself; an instance of the
// device's template (named template_name(type), datatype Template or none, is_definition false,
// template_ref absent or the type's) is its members, each by name, as Ignition's MQTT Engine
// writes a UDT member. Fails (invalid_argument, naming the metric) for a Template metric that is
// not such an instance: a definition, another type's, a member by alias or itself a template.
// `templates`: whether this node publishes instances; without, a Template metric is refused.
Result<std::vector<Metric>> command_writes(std::optional<ModuleType> type, const Metric& metric,
                                           bool templates);

}  // namespace ioport::sparkplug
