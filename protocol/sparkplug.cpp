#include "protocol/sparkplug.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>

#include <fmt/format.h>

#include "protocol/json_reader.hpp"

namespace ioport::sparkplug {
namespace {

constexpr std::array<std::string_view, 9> type_names{
    "NBIRTH", "NDEATH", "DBIRTH", "DDEATH", "NDATA", "DDATA", "NCMD", "DCMD", "STATE"};

std::vector<std::string_view> split(std::string_view text, char separator) {
    std::vector<std::string_view> parts;
    for (;;) {
        const auto at = text.find(separator);
        parts.push_back(text.substr(0, at));
        if (at == std::string_view::npos) return parts;
        text.remove_prefix(at + 1);
    }
}

Unexpected<Error> refused(std::string_view name, std::string why) {
    return fail(Errc::invalid_argument, fmt::format("metric {}: {}", name, std::move(why)));
}

std::string_view type_of(const Value& value) {
    switch (value.index()) {
        case 0:
            return "Boolean";
        case 1:
            return "an integer";
        case 2:
            return "Float";
        default:
            return "String";
    }
}

// Sparkplug's name of a point: a number after a word goes after a slash ("out3" is out/3,
// "value0" value/0); words without one stay as they are.
std::string metric_name(std::string_view point) {
    const auto digit = point.find_first_of("0123456789");
    if (digit == std::string_view::npos || digit == 0) return std::string(point);
    return fmt::format("{}/{}", point.substr(0, digit), point.substr(digit));
}

DataType datatype_of(gateway::PointType type) {
    switch (type) {
        case gateway::PointType::boolean:
            return DataType::boolean;
        case gateway::PointType::uint8:
            return DataType::uint8;
        case gateway::PointType::uint16:
            return DataType::uint16;
        case gateway::PointType::float32:
            break;
    }
    return DataType::float32;
}

// The value of a command to a metric of `type`, in range, or why not.
Result<std::uint64_t> command_value(std::string_view name, DataType type,
                                    const std::optional<Value>& value, std::uint64_t max) {
    if (!value) return refused(name, "a null value is not a command");
    if (type == DataType::boolean) {
        if (const auto* flag = std::get_if<bool>(&*value)) return *flag ? 1u : 0u;
        return refused(name, fmt::format("expected Boolean, got {}", type_of(*value)));
    }
    const auto* number = std::get_if<std::uint64_t>(&*value);
    if (number == nullptr)
        return refused(name, fmt::format("expected {}, got {}", to_string(type), type_of(*value)));
    if (*number > max) return refused(name, fmt::format("{} is over {}", *number, max));
    return *number;
}

}  // namespace

std::string_view to_string(MessageType type) {
    return type_names[static_cast<std::size_t>(type)];
}

std::string topic(std::string_view group, MessageType type, std::string_view node,
                  std::string_view device) {
    auto text = fmt::format("{}/{}/{}/{}", namespace_prefix, group, to_string(type), node);
    if (!device.empty()) {
        text += '/';
        text += device;
    }
    return text;
}

std::string state_topic(std::string_view host_id) {
    return fmt::format("{}/STATE/{}", namespace_prefix, host_id);
}

std::optional<Topic> parse_topic(std::string_view text) {
    const auto parts = split(text, '/');
    if (parts.size() < 3 || parts[0] != namespace_prefix) return std::nullopt;
    if (parts[1] == "STATE") {
        if (parts.size() != 3 || parts[2].empty()) return std::nullopt;
        return Topic{MessageType::state, {}, std::string(parts[2]), {}};
    }
    if (parts.size() != 4 && parts.size() != 5) return std::nullopt;
    std::optional<MessageType> type;
    for (std::size_t i = 0; i + 1 < type_names.size(); ++i)
        if (parts[2] == type_names[i]) type = static_cast<MessageType>(i);
    if (!type || parts[1].empty() || parts[3].empty()) return std::nullopt;
    const bool device_message = *type == MessageType::dbirth || *type == MessageType::ddeath ||
                                *type == MessageType::ddata || *type == MessageType::dcmd;
    if (device_message != (parts.size() == 5) || (device_message && parts[4].empty()))
        return std::nullopt;
    return Topic{*type, std::string(parts[1]), std::string(parts[3]),
                 device_message ? std::string(parts[4]) : std::string()};
}

Result<> check_id(std::string_view id) {
    if (id.empty()) return fail(Errc::invalid_argument, "must not be empty");
    for (const char c : id) {
        if (c == '/' || c == '+' || c == '#')
            return fail(Errc::invalid_argument,
                        fmt::format("'{}' contains '{}', which MQTT topics reserve", id, c));
        if (static_cast<unsigned char>(c) < 0x20 || c == 0x7F)
            return fail(Errc::invalid_argument,
                        fmt::format("'{}' contains a control character", printable(id)));
    }
    return {};
}

std::string_view to_string(DataType type) {
    switch (type) {
        case DataType::int64:
            return "Int64";
        case DataType::uint8:
            return "UInt8";
        case DataType::uint16:
            return "UInt16";
        case DataType::uint64:
            return "UInt64";
        case DataType::float32:
            return "Float";
        case DataType::boolean:
            return "Boolean";
        case DataType::string:
            return "String";
    }
    return "Unknown";
}

Result<HostState> parse_state(std::string_view json) {
    if (json.size() > max_state_bytes)
        return fail(Errc::invalid_argument,
                    fmt::format("{} bytes, more than the {} a STATE may have", json.size(),
                                max_state_bytes));
    auto object = JsonObject::parse(json);
    if (!object) return Unexpected(object.error());
    const auto online = object->boolean("online");
    if (!online) return fail(Errc::malformed, R"("online" is not true or false)");
    HostState host{*online, 0};
    if (object->has("timestamp")) {
        const auto timestamp = object->unsigned_integer("timestamp");
        if (!timestamp)
            return fail(Errc::malformed, R"("timestamp" is not a whole number of milliseconds)");
        host.timestamp = *timestamp;
    }
    return host;
}

std::string state_json(bool online, std::uint64_t timestamp) {
    return fmt::format(R"({{"online":{},"timestamp":{}}})", online, timestamp);
}

std::string device_id(std::string_view link, std::optional<ModuleAddress> module, char separator) {
    if (!module) return fmt::format("{}{}id2", link, separator);
    return fmt::format("{}{}{}{}{}", link, separator, name(module->type), separator,
                       module->number);
}

std::vector<MetricSpec> module_metrics(std::optional<ModuleType> type) {
    std::vector<MetricSpec> metrics;
    for (const auto& point : gateway::module_points(type))
        metrics.push_back({metric_name(point.id), datatype_of(point.type), point.writable});
    return metrics;
}

Value metric_value(const gateway::PointValue& value) {
    return std::visit([](const auto& v) { return Value(v); }, value);
}

std::vector<std::vector<Property>> module_properties(std::optional<ModuleAddress> module,
                                                     const gateway::ModuleTags& tags) {
    const auto type = module ? std::optional(module->type) : std::nullopt;
    auto out = std::vector<std::vector<Property>>(module_metrics(type).size());
    if (!module) return out;  // the ID-2 has no names of its own
    // "boiler 1: supply temperature", "boiler 1", "acm3p 0: supply temperature", or nothing.
    const bool module_named = !tags.name.empty() && tags.name != to_string(*module);
    const auto document = [&](std::vector<Property>& properties, const std::string& point) {
        if (point.empty() && !module_named) return;
        properties.push_back(
            {"documentation", point.empty() ? tags.name : fmt::format("{}: {}", tags.name, point)});
    };
    const auto channels = tags.channels.size();
    if (channels > 0) {  // raw/0…raw/n-1, then value/0…value/n-1
        for (std::size_t ch = 0; ch < channels && channels * 2 <= out.size(); ++ch) {
            const auto& tag = tags.channels[ch];
            auto& value = out[channels + ch];
            if (!tag.unit.empty()) value.push_back({"engUnit", tag.unit});
            value.push_back({"engLow", tag.range[0]});
            value.push_back({"engHigh", tag.range[1]});
            document(value, tag.name);
            document(out[ch], tag.name);
        }
        return out;
    }
    for (std::size_t i = 0; i < out.size(); ++i)  // in/k or out/k then word, or colour, pos, neg
        document(out[i], i < tags.points.size() && gateway::has_points(module->type)
                             ? tags.points[i]
                             : std::string());
    return out;
}

bool operator==(const Template& a, const Template& b) {
    return a.version == b.version && a.template_ref == b.template_ref &&
           a.is_definition == b.is_definition && a.members == b.members;
}

std::string template_name(std::optional<ModuleType> type) {
    return type ? std::string(name(*type)) : std::string("id2");
}

std::string definition_name(std::optional<ModuleType> type) {
    return fmt::format("_types_/{}", template_name(type));
}

Metric template_definition(std::optional<ModuleType> type, std::uint64_t timestamp) {
    Template definition{std::string(template_version), {}, true, {}};
    for (const auto& spec : module_metrics(type))
        definition.members.push_back(Metric{spec.name, std::nullopt, std::nullopt,
                                            static_cast<std::uint32_t>(spec.type), std::nullopt});
    Metric metric{definition_name(type), std::nullopt, timestamp, template_datatype, std::nullopt};
    metric.template_value = std::move(definition);
    return metric;
}

Metric template_instance(std::optional<ModuleType> type, std::vector<Metric> members,
                         std::optional<std::uint64_t> alias, std::uint64_t timestamp) {
    Metric metric{template_name(type), alias, timestamp, template_datatype, std::nullopt};
    metric.template_value = Template{{}, template_name(type), false, std::move(members)};
    return metric;
}

std::vector<Metric> to_flat(std::vector<Metric> metrics) {
    std::vector<Metric> flat;
    flat.reserve(metrics.size());
    for (auto& metric : metrics) {
        if (!metric.template_value) {
            flat.push_back(std::move(metric));
            continue;
        }
        for (auto& member : metric.template_value->members) {
            member.is_historical = member.is_historical || metric.is_historical;
            if (!member.timestamp) member.timestamp = metric.timestamp;
            flat.push_back(std::move(member));
        }
    }
    return flat;
}

Result<std::vector<Metric>> command_writes(std::optional<ModuleType> type, const Metric& metric,
                                           bool templates) {
    if (!metric.template_value && metric.datatype != template_datatype)
        return std::vector<Metric>{metric};
    const auto what = metric.name.empty() ? fmt::format("alias {}", metric.alias.value_or(0))
                                          : std::string(metric.name);
    if (!templates)
        return refused(what, "a Template, and this edge node publishes none (mqtt.templates)");
    const auto& instance = metric.template_value;
    const auto own = template_name(type);
    if (!instance) return refused(what, "datatype Template without a Template value");
    if (metric.name != own)
        return refused(what, fmt::format("not this device's template instance, {}", own));
    if (instance->is_definition)
        return refused(what, "a template definition is not a command: send an instance");
    if (!instance->template_ref.empty() && instance->template_ref != own)
        return refused(what, fmt::format("template_ref {} is not {}",
                                         printable(instance->template_ref, 64), own));
    for (const auto& member : instance->members) {
        if (member.name.empty())
            return refused(what, "a member without a name (members go by name)");
        if (member.template_value || member.datatype == template_datatype)
            return refused(what, fmt::format("member {} is a Template", member.name));
    }
    return instance->members;
}

std::size_t writable_metrics(std::optional<ModuleType> type) {
    const auto metrics = module_metrics(type);
    return static_cast<std::size_t>(std::ranges::count(metrics, true, &MetricSpec::writable));
}

namespace {

// Calls on(field, bytes) for every length-delimited field of a protobuf message, skipping the
// others, without decoding anything. False when the bytes are not a sequence of protobuf fields.
template <typename On>
bool walk_fields(std::span<const std::uint8_t> bytes, On&& on) {
    std::size_t at = 0;
    const auto varint = [&]() -> std::optional<std::uint64_t> {
        std::uint64_t value = 0;
        for (int shift = 0; shift < 64 && at < bytes.size(); shift += 7) {
            const auto byte = bytes[at++];
            value |= std::uint64_t{byte & 0x7Fu} << shift;
            if ((byte & 0x80) == 0) return value;
        }
        return std::nullopt;
    };
    const auto skip = [&](std::uint64_t length) {
        if (length > bytes.size() - at) return false;
        at += static_cast<std::size_t>(length);
        return true;
    };
    while (at < bytes.size()) {
        const auto key = varint();
        if (!key || *key >> 3 == 0) return false;
        bool ok = false;
        switch (*key & 7) {
            case 0:
                ok = varint().has_value();
                break;
            case 1:
                ok = skip(8);
                break;
            case 2: {
                const auto length = varint();
                const auto start = at;
                ok = length && skip(*length);
                if (ok && !on(*key >> 3, bytes.subspan(start, at - start))) return false;
                break;
            }
            case 5:
                ok = skip(4);
                break;
            default:  // groups (3, 4), which Sparkplug does not use, and wire types 6, 7
                break;
        }
        if (!ok) return false;
    }
    return true;
}

// Payload field 2 is a metric; Metric field 18 its Template value; Template field 2 a member.
constexpr std::uint64_t payload_metrics = 2;
constexpr std::uint64_t metric_template = 18;
constexpr std::uint64_t template_members = 2;

}  // namespace

Result<std::size_t> count_command_metrics(std::span<const std::uint8_t> bytes) {
    std::size_t metrics = 0;
    const bool ok = walk_fields(bytes, [&](std::uint64_t field, auto metric) {
        if (field != payload_metrics) return true;
        std::size_t members = 0;
        bool instance = false;
        const bool inner = walk_fields(metric, [&](std::uint64_t f, auto value) {
            if (f != metric_template) return true;
            instance = true;
            return walk_fields(value, [&](std::uint64_t m, auto) {
                if (m == template_members) ++members;
                return true;
            });
        });
        metrics += instance ? std::max<std::size_t>(members, 1) : 1;
        return inner;
    });
    if (!ok) return fail(Errc::malformed, "not a Sparkplug B payload (bad protobuf field)");
    return metrics;
}

std::size_t command_metrics(const std::vector<Metric>& metrics) {
    std::size_t count = 0;
    for (const auto& metric : metrics)
        count += metric.template_value
                     ? std::max<std::size_t>(metric.template_value->members.size(), 1)
                     : 1;
    return count;
}

Result<std::size_t> count_metrics(std::span<const std::uint8_t> bytes) {
    std::size_t metrics = 0;
    const bool ok = walk_fields(bytes, [&](std::uint64_t field, auto) {
        if (field == payload_metrics) ++metrics;
        return true;
    });
    if (!ok) return fail(Errc::malformed, "not a Sparkplug B payload (bad protobuf field)");
    return metrics;
}

Result<gateway::WritePlan> plan_command(std::optional<ModuleAddress> module, std::string_view name,
                                        std::uint32_t datatype, const std::optional<Value>& value) {
    const auto metrics = module_metrics(module ? std::optional(module->type) : std::nullopt);
    const auto spec = std::find_if(metrics.begin(), metrics.end(),
                                   [&](const MetricSpec& m) { return m.name == name; });
    if (spec == metrics.end()) return refused(name, "no such metric on this device");
    if (!spec->writable) return refused(name, "read-only: an input of the device");
    // A host writes what the DBIRTH announced; another type is a host's mistake, not a value.
    if (datatype != 0 && datatype != static_cast<std::uint32_t>(spec->type))
        return refused(name, fmt::format("declared datatype {}, but the metric is {}", datatype,
                                         to_string(spec->type)));
    const auto& point = gateway::module_points(
        module ? std::optional(module->type)
               : std::nullopt)[static_cast<std::size_t>(spec - metrics.begin())];
    auto number = command_value(name, spec->type, value, gateway::max_number(point.type));
    if (!number) return Unexpected(number.error());
    auto plan = gateway::plan_point_write(module, point.id, *number);
    if (!plan) return refused(name, plan.error().message);
    return plan;
}

}  // namespace ioport::sparkplug
