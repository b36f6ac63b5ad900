// The payload's wire format: the part of protocol/sparkplug.hpp that needs protobuf, in its own
// library (ioport_sparkplug) so that only what publishes or decodes payloads links it.
#include <algorithm>
#include <limits>

#include <fmt/format.h>

#include "protocol/sparkplug.hpp"
#include "protocol/sparkplug_b.pb.h"

namespace ioport::sparkplug {
namespace {

namespace wire = ioport::sparkplug::wire;

void set_value(wire::Payload::Metric& out, std::uint32_t datatype, const Value& value) {
    std::visit(
        [&](const auto& v) {
            using V = std::decay_t<decltype(v)>;
            if constexpr (std::is_same_v<V, bool>) {
                out.set_boolean_value(v);
            } else if constexpr (std::is_same_v<V, std::uint64_t>) {
                // Sparkplug 3.0 §6.4.17: 8- to 32-bit integers in int_value, 64-bit in long_value.
                if (datatype == static_cast<std::uint32_t>(DataType::uint64) ||
                    datatype == static_cast<std::uint32_t>(DataType::int64))
                    out.set_long_value(v);
                else
                    out.set_int_value(static_cast<std::uint32_t>(v));
            } else if constexpr (std::is_same_v<V, float>) {
                out.set_float_value(v);
            } else {
                out.set_string_value(v);
            }
        },
        value);
}

std::optional<Value> value_of(const wire::Payload::Metric& metric) {
    if (metric.is_null()) return std::nullopt;
    switch (metric.value_case()) {
        case wire::Payload::Metric::kIntValue:
            return Value(std::uint64_t{metric.int_value()});
        case wire::Payload::Metric::kLongValue:
            return Value(std::uint64_t{metric.long_value()});
        case wire::Payload::Metric::kFloatValue:
            return Value(metric.float_value());
        case wire::Payload::Metric::kDoubleValue:
            return Value(static_cast<float>(metric.double_value()));
        case wire::Payload::Metric::kBooleanValue:
            return Value(metric.boolean_value());
        case wire::Payload::Metric::kStringValue:
            return Value(metric.string_value());
        case wire::Payload::Metric::kBytesValue:
        case wire::Payload::Metric::kDatasetValue:
        case wire::Payload::Metric::kTemplateValue:
        case wire::Payload::Metric::kExtensionValue:
        case wire::Payload::Metric::VALUE_NOT_SET:
            break;
    }
    return std::nullopt;
}

// Sparkplug 3.0 §6.4.16: every property value names its type (payloads-metric-propertyvalue-
// type-req); the keys and values arrays have the same length.
constexpr std::uint32_t property_double = 10;
constexpr std::uint32_t property_string = 12;

void set_properties(wire::Payload::PropertySet& set, const std::vector<Property>& properties) {
    for (const auto& property : properties) {
        set.add_keys(property.key);
        auto& value = *set.add_values();
        if (const auto* number = std::get_if<double>(&property.value)) {
            value.set_type(property_double);
            value.set_double_value(*number);
        } else {
            value.set_type(property_string);
            value.set_string_value(std::get<std::string>(property.value));
        }
    }
}

// The Double, Float and String properties of a set whose keys and values pair up; others are
// skipped (ioportd acts on none: it reads properties back in its tests and its fuzzer).
std::vector<Property> properties_of(const wire::Payload::PropertySet& set) {
    std::vector<Property> out;
    const auto count = std::min(set.keys_size(), set.values_size());
    for (int i = 0; i < count; ++i) {
        const auto& value = set.values(i);
        switch (value.value_case()) {
            case wire::Payload::PropertyValue::kDoubleValue:
                out.push_back({set.keys(i), value.double_value()});
                break;
            case wire::Payload::PropertyValue::kFloatValue:
                out.push_back({set.keys(i), static_cast<double>(value.float_value())});
                break;
            case wire::Payload::PropertyValue::kStringValue:
                out.push_back({set.keys(i), value.string_value()});
                break;
            case wire::Payload::PropertyValue::kIntValue:
            case wire::Payload::PropertyValue::kLongValue:
            case wire::Payload::PropertyValue::kBooleanValue:
            case wire::Payload::PropertyValue::kPropertysetValue:
            case wire::Payload::PropertyValue::kPropertysetsValue:
            case wire::Payload::PropertyValue::kExtensionValue:
            case wire::Payload::PropertyValue::VALUE_NOT_SET:
                break;
        }
    }
    return out;
}

void set_metric(wire::Payload::Metric& m, const Metric& metric, Datatypes datatypes) {
    if (!metric.name.empty()) m.set_name(metric.name);
    if (metric.alias) m.set_alias(*metric.alias);
    if (metric.timestamp) m.set_timestamp(*metric.timestamp);
    switch (datatypes) {
        case Datatypes::sent:
            m.set_datatype(metric.datatype);
            break;
        case Datatypes::left_out:
            break;
    }
    if (metric.value)
        set_value(m, metric.datatype, *metric.value);
    else if (!metric.template_value)
        m.set_is_null(true);
    if (metric.is_historical) m.set_is_historical(true);
    if (!metric.properties.empty()) set_properties(*m.mutable_properties(), metric.properties);
    if (const auto& t = metric.template_value) {
        auto& out = *m.mutable_template_value();
        if (!t->version.empty()) out.set_version(t->version);
        for (const auto& member : t->members)
            set_metric(*out.add_metrics(), member, datatypes);
        if (!t->template_ref.empty()) out.set_template_ref(t->template_ref);
        // Sparkplug 3.0 payloads-template-is-definition: on every definition and instance.
        out.set_is_definition(t->is_definition);
    }
}

Result<Metric> metric_of(const wire::Payload::Metric& m, int depth) {
    Metric metric;
    metric.name = m.name();
    if (m.has_alias()) metric.alias = m.alias();
    if (m.has_timestamp()) metric.timestamp = m.timestamp();
    metric.datatype = m.datatype();
    metric.value = value_of(m);
    metric.is_historical = m.is_historical();
    if (m.has_properties()) metric.properties = properties_of(m.properties());
    if (m.has_template_value()) {
        if (depth >= max_template_depth)
            return fail(Errc::malformed,
                        fmt::format("templates nested deeper than {}", max_template_depth));
        const auto& in = m.template_value();
        Template t{in.version(), in.template_ref(), in.is_definition(), {}};
        t.members.reserve(static_cast<std::size_t>(in.metrics_size()));
        for (const auto& member : in.metrics()) {
            auto decoded = metric_of(member, depth + 1);
            if (!decoded) return decoded;
            t.members.push_back(std::move(*decoded));
        }
        metric.template_value = std::move(t);
    }
    return metric;
}

}  // namespace

std::vector<std::uint8_t> encode(const Payload& payload, Datatypes datatypes) {
    wire::Payload out;
    out.set_timestamp(payload.timestamp);
    if (payload.seq) out.set_seq(*payload.seq);
    for (const auto& metric : payload.metrics)
        set_metric(*out.add_metrics(), metric, datatypes);
    std::vector<std::uint8_t> bytes(out.ByteSizeLong());
    out.SerializeToArray(bytes.data(), static_cast<int>(bytes.size()));
    return bytes;
}

Result<Payload> decode(std::span<const std::uint8_t> bytes) {
    wire::Payload in;
    if (bytes.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()) ||
        !in.ParseFromArray(bytes.data(), static_cast<int>(bytes.size())))
        return fail(Errc::malformed, "not a Sparkplug B payload (protobuf decoding failed)");
    Payload payload;
    payload.timestamp = in.timestamp();
    if (in.has_seq()) payload.seq = in.seq();
    payload.metrics.reserve(static_cast<std::size_t>(in.metrics_size()));
    for (const auto& m : in.metrics()) {
        auto metric = metric_of(m, 0);
        if (!metric) return Unexpected(metric.error());
        payload.metrics.push_back(std::move(*metric));
    }
    return payload;
}

namespace {
constexpr std::uint8_t stored_version = 1;
}

std::vector<std::uint8_t> encode_stored(const StoredData& data) {
    const auto length = std::min(data.device.size(), std::size_t{0xFFFF});
    const auto payload = encode(data.payload);
    std::vector<std::uint8_t> bytes;
    bytes.reserve(3 + length + payload.size());
    bytes.push_back(stored_version);
    bytes.push_back(static_cast<std::uint8_t>(length & 0xFF));
    bytes.push_back(static_cast<std::uint8_t>(length >> 8));
    bytes.insert(bytes.end(), data.device.data(), data.device.data() + length);
    bytes.insert(bytes.end(), payload.begin(), payload.end());
    return bytes;
}

Result<StoredData> decode_stored(std::span<const std::uint8_t> bytes) {
    if (bytes.size() < 3 || bytes[0] != stored_version)
        return fail(Errc::malformed, "not a stored DDATA record (no version 1 header)");
    const std::size_t length = bytes[1] | std::size_t{bytes[2]} << 8;
    if (bytes.size() - 3 < length)
        return fail(Errc::malformed, "a stored DDATA record shorter than its device id");
    StoredData data;
    data.device.assign(bytes.begin() + 3, bytes.begin() + 3 + static_cast<std::ptrdiff_t>(length));
    auto payload = decode(bytes.subspan(3 + length));
    if (!payload) return Unexpected(payload.error());
    data.payload = std::move(*payload);
    return data;
}

Result<Payload> decode_command(std::span<const std::uint8_t> bytes, std::size_t max_metrics) {
    // Both bounds before protobuf sees the bytes: its parse of a large payload is itself the
    // cost (an 11 MB DCMD of 100,000s of metrics held the loop for seconds).
    if (bytes.size() > max_command_bytes(max_metrics))
        return fail(Errc::invalid_argument,
                    fmt::format("refused whole: {} bytes, more than the {} a command of at most {} "
                                "metric(s) may take",
                                bytes.size(), max_command_bytes(max_metrics), max_metrics));
    const auto metrics = count_command_metrics(bytes);
    if (!metrics) return Unexpected(metrics.error());
    if (*metrics > max_metrics)
        return fail(Errc::invalid_argument,
                    fmt::format("refused whole: it names {} metrics, and the device has {} "
                                "writable one(s)",
                                *metrics, max_metrics));
    return decode(bytes);
}

}  // namespace ioport::sparkplug
