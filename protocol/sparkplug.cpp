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

std::string device_id(std::string_view link, std::optional<ModuleAddress> module) {
    if (!module) return fmt::format("{}.id2", link);
    return fmt::format("{}.{}.{}", link, name(module->type), module->number);
}

std::vector<MetricSpec> module_metrics(std::optional<ModuleType> type) {
    std::vector<MetricSpec> metrics;
    const auto bits = [&](std::string_view prefix, bool writable) {
        for (int k = 0; k < 16; ++k)
            metrics.push_back({fmt::format("{}/{}", prefix, k), DataType::boolean, writable});
        metrics.push_back({"word", DataType::uint16, writable});
    };
    if (!type) {
        metrics.push_back({"stop", DataType::boolean, false});
        metrics.push_back({"count", DataType::uint16, false});
        metrics.push_back({"reset", DataType::boolean, true});
        return metrics;
    }
    switch (*type) {
        case ModuleType::dim16:
        case ModuleType::lim16:
            bits("in", false);
            break;
        case ModuleType::dom16:
            bits("out", true);
            break;
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            for (int ch = 0; ch < reply_words(*type); ++ch)
                metrics.push_back({fmt::format("raw/{}", ch), DataType::uint16, false});
            for (int ch = 0; ch < reply_words(*type); ++ch)
                metrics.push_back({fmt::format("value/{}", ch), DataType::float32, false});
            break;
        case ModuleType::rgbdm:
            metrics.push_back({"colour", DataType::uint8, true});
            break;
        case ModuleType::mux8m:
            metrics.push_back({"pos", DataType::uint8, true});
            metrics.push_back({"neg", DataType::uint8, true});
            break;
    }
    return metrics;
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

std::vector<std::optional<Value>> module_values(std::optional<ModuleType> type,
                                                const ModuleValues& values) {
    std::vector<std::optional<Value>> out;
    const auto bits = [&](std::optional<std::uint16_t> word) {
        for (int k = 0; k < 16; ++k)
            out.push_back(word ? std::optional<Value>((*word >> k & 1) != 0) : std::nullopt);
        out.push_back(word ? std::optional<Value>(std::uint64_t{*word}) : std::nullopt);
    };
    if (!type) {
        out.push_back(values.stop ? std::optional<Value>(*values.stop) : std::nullopt);
        out.push_back(values.count ? std::optional<Value>(std::uint64_t{*values.count})
                                   : std::nullopt);
        out.emplace_back(false);
        return out;
    }
    const auto& reading = values.reading;
    switch (*type) {
        case ModuleType::dim16:
        case ModuleType::lim16:
            bits(reading ? std::optional(reading->raw[0]) : std::nullopt);
            break;
        case ModuleType::dom16:
            bits(values.output);
            break;
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::dccim:
        case ModuleType::dcvim: {
            const auto channels = static_cast<std::size_t>(reply_words(*type));
            for (std::size_t ch = 0; ch < channels; ++ch)
                out.push_back(reading ? std::optional<Value>(std::uint64_t{reading->raw[ch]})
                                      : std::nullopt);
            for (std::size_t ch = 0; ch < channels; ++ch)
                out.push_back(reading ? std::optional<Value>(gateway::channel_value(
                                            *type, reading->raw[ch], *values.tags, ch))
                                      : std::nullopt);
            break;
        }
        case ModuleType::rgbdm:
            out.push_back(values.output ? std::optional<Value>(std::uint64_t{*values.output})
                                        : std::nullopt);
            break;
        case ModuleType::mux8m:
            out.push_back(values.output ? std::optional<Value>(
                                              static_cast<std::uint64_t>(*values.output >> 8))
                                        : std::nullopt);
            out.push_back(values.output ? std::optional<Value>(
                                              static_cast<std::uint64_t>(*values.output & 0xFF))
                                        : std::nullopt);
            break;
    }
    return out;
}

std::vector<std::size_t> changed_metrics(std::optional<ModuleType> type,
                                         const std::vector<std::optional<Value>>& published,
                                         const std::vector<std::optional<Value>>& now,
                                         double deadband) {
    const auto moved = [&](std::size_t i) {
        if (published[i].has_value() != now[i].has_value()) return true;
        if (!now[i]) return false;
        const auto* before = std::get_if<float>(&*published[i]);
        const auto* after = std::get_if<float>(&*now[i]);
        if (before != nullptr && after != nullptr && deadband > 0)
            return std::fabs(static_cast<double>(*after) - static_cast<double>(*before)) > deadband;
        return *published[i] != *now[i];
    };
    // Analog modules publish raw/0…raw/n-1, then value/0…value/n-1: a raw word goes with its value.
    const auto analog = type && (*type == ModuleType::acm3p || *type == ModuleType::acm3c ||
                                 *type == ModuleType::dccim || *type == ModuleType::dcvim);
    const auto channels = analog ? static_cast<std::size_t>(reply_words(*type)) : 0;
    std::vector<std::size_t> changed;
    const auto count = std::min(published.size(), now.size());
    for (std::size_t i = 0; i < count; ++i)
        if (i < 2 * channels ? moved(channels + i % channels) : moved(i)) changed.push_back(i);
    return changed;
}

std::size_t writable_metrics(std::optional<ModuleType> type) {
    const auto metrics = module_metrics(type);
    return static_cast<std::size_t>(std::ranges::count(metrics, true, &MetricSpec::writable));
}

Result<std::size_t> count_metrics(std::span<const std::uint8_t> bytes) {
    const auto malformed = [] {
        return fail(Errc::malformed, "not a Sparkplug B payload (bad protobuf field)");
    };
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
    std::size_t metrics = 0;
    while (at < bytes.size()) {
        const auto key = varint();
        if (!key || *key >> 3 == 0) return malformed();
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
                ok = length && skip(*length);
                if (*key >> 3 == 2) ++metrics;
                break;
            }
            case 5:
                ok = skip(4);
                break;
            default:  // groups (3, 4), which Sparkplug does not use, and wire types 6, 7
                break;
        }
        if (!ok) return malformed();
    }
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
    gateway::WritePlan plan;
    if (!module) {  // the ID-2's reset
        auto reset = command_value(name, spec->type, value, 1);
        if (!reset) return Unexpected(reset.error());
        plan.reset_counter = *reset != 0;
        return plan;
    }
    // The metric's type bounds the number; the module's own rule (validate_output_value, as for
    // a Modbus write) bounds the value.
    const auto max = spec->type == DataType::boolean ? 1u
                     : spec->type == DataType::uint8 ? 0xFFu
                                                     : 0xFFFFu;
    auto number = command_value(name, spec->type, value, max);
    if (!number) return Unexpected(number.error());
    const auto v = static_cast<std::uint16_t>(*number);
    gateway::OutputChange change{*module, 0xFFFF, v};
    if (name.starts_with("out/")) {
        const auto bit = static_cast<int>(spec - metrics.begin());  // out/0 … out/15 come first
        change.mask = static_cast<std::uint16_t>(1u << bit);
        change.value = static_cast<std::uint16_t>(v << bit);
    } else if (name == "pos") {
        change.mask = 0xFF00;
        change.value = static_cast<std::uint16_t>(v << 8);
    } else if (name == "neg") {
        change.mask = 0x00FF;
    }
    if (auto valid = validate_output_value(module->type, change.value); !valid)
        return refused(name, valid.error().message);
    plan.changes.push_back(change);
    return plan;
}

}  // namespace ioport::sparkplug
