#include "protocol/points.hpp"

#include <array>
#include <cmath>

#include <fmt/format.h>

namespace ioport::gateway {
namespace {

std::vector<PointSpec> points_of(std::optional<ModuleType> type) {
    std::vector<PointSpec> points;
    const auto bits = [&](std::string_view prefix, bool writable) {
        for (int k = 0; k < 16; ++k)
            points.push_back({fmt::format("{}{}", prefix, k), PointType::boolean, writable});
        points.push_back({"word", PointType::uint16, writable});
    };
    if (!type) {
        points.push_back({"stop", PointType::boolean, false});
        points.push_back({"count", PointType::uint16, false});
        points.push_back({"reset", PointType::boolean, true, true});
        return points;
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
                points.push_back({fmt::format("raw{}", ch), PointType::uint16, false});
            for (int ch = 0; ch < reply_words(*type); ++ch)
                points.push_back({fmt::format("value{}", ch), PointType::float32, false});
            break;
        case ModuleType::rgbdm:
            points.push_back({"colour", PointType::uint8, true});
            break;
        case ModuleType::mux8m:
            points.push_back({"pos", PointType::uint8, true});
            points.push_back({"neg", PointType::uint8, true});
            break;
    }
    return points;
}

bool is_analog(std::optional<ModuleType> type) {
    return type && (*type == ModuleType::acm3p || *type == ModuleType::acm3c ||
                    *type == ModuleType::dccim || *type == ModuleType::dcvim);
}

Unexpected<Error> refused(std::string why) {
    return fail(Errc::invalid_argument, std::move(why));
}

std::optional<bool> parse_switch(std::string_view text) {
    for (const auto on : {"ON", "on", "1", "true"})
        if (text == on) return true;
    for (const auto off : {"OFF", "off", "0", "false"})
        if (text == off) return false;
    return std::nullopt;
}

// A whole number 0…max, decimal or 0x hex, nothing else (no sign, no fraction, no space).
std::optional<std::uint64_t> parse_number(std::string_view text, std::uint64_t max) {
    int base = 10;
    if (text.starts_with("0x") || text.starts_with("0X")) {
        base = 16;
        text.remove_prefix(2);
    }
    if (text.empty() || text.size() > 8) return std::nullopt;
    std::uint64_t number = 0;
    for (const char c : text) {
        int digit = -1;
        if (c >= '0' && c <= '9') digit = c - '0';
        if (base == 16 && c >= 'a' && c <= 'f') digit = c - 'a' + 10;
        if (base == 16 && c >= 'A' && c <= 'F') digit = c - 'A' + 10;
        if (digit < 0 || digit >= base) return std::nullopt;
        number = number * static_cast<std::uint64_t>(base) + static_cast<std::uint64_t>(digit);
    }
    if (number > max) return std::nullopt;
    return number;
}

}  // namespace

const std::vector<PointSpec>& module_points(std::optional<ModuleType> type) {
    static const auto by_type = [] {
        std::array<std::vector<PointSpec>, module_type_count + 1> all;
        for (std::size_t t = 0; t < module_type_count; ++t)
            all[t] = points_of(static_cast<ModuleType>(t));
        all[module_type_count] = points_of(std::nullopt);
        return all;
    }();
    return by_type[type ? static_cast<std::size_t>(*type) : module_type_count];
}

std::optional<FoundPoint> find_point(std::optional<ModuleType> type, std::string_view id) {
    const auto& points = module_points(type);
    for (std::size_t i = 0; i < points.size(); ++i)
        if (points[i].id == id) return FoundPoint{&points[i], i};
    return std::nullopt;
}

void point_values(std::optional<ModuleType> type, const ModuleReadings& now, const ModuleTags& tags,
                  std::vector<std::optional<PointValue>>& out) {
    out.clear();
    const auto bits = [&](std::optional<std::uint16_t> word) {
        for (int k = 0; k < 16; ++k)
            out.push_back(word ? std::optional<PointValue>((*word >> k & 1) != 0) : std::nullopt);
        out.push_back(word ? std::optional<PointValue>(std::uint64_t{*word}) : std::nullopt);
    };
    if (!type) {
        out.push_back(now.stop ? std::optional<PointValue>(*now.stop) : std::nullopt);
        out.push_back(now.count ? std::optional<PointValue>(std::uint64_t{*now.count})
                                : std::nullopt);
        out.emplace_back(false);
        return;
    }
    const auto& reading = now.reading;
    switch (*type) {
        case ModuleType::dim16:
        case ModuleType::lim16:
            bits(reading ? std::optional(reading->raw[0]) : std::nullopt);
            break;
        case ModuleType::dom16:
            bits(now.output);
            break;
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::dccim:
        case ModuleType::dcvim: {
            const auto channels = static_cast<std::size_t>(reply_words(*type));
            for (std::size_t ch = 0; ch < channels; ++ch)
                out.push_back(reading ? std::optional<PointValue>(std::uint64_t{reading->raw[ch]})
                                      : std::nullopt);
            for (std::size_t ch = 0; ch < channels; ++ch)
                out.push_back(reading ? std::optional<PointValue>(
                                            channel_value(*type, reading->raw[ch], tags, ch))
                                      : std::nullopt);
            break;
        }
        case ModuleType::rgbdm:
            out.push_back(now.output ? std::optional<PointValue>(std::uint64_t{*now.output})
                                     : std::nullopt);
            break;
        case ModuleType::mux8m:
            out.push_back(
                now.output ? std::optional<PointValue>(static_cast<std::uint64_t>(*now.output >> 8))
                           : std::nullopt);
            out.push_back(now.output ? std::optional<PointValue>(
                                           static_cast<std::uint64_t>(*now.output & 0xFF))
                                     : std::nullopt);
            break;
    }
}

std::vector<std::size_t> changed_points(std::optional<ModuleType> type,
                                        std::span<const std::optional<PointValue>> published,
                                        std::span<const std::optional<PointValue>> now,
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
    // Analog modules have raw0…rawN-1, then value0…valueN-1: a raw word goes with its value.
    const auto channels = is_analog(type) ? static_cast<std::size_t>(reply_words(*type)) : 0;
    std::vector<std::size_t> changed;
    const auto count = std::min(published.size(), now.size());
    for (std::size_t i = 0; i < count; ++i)
        if (i < 2 * channels ? moved(channels + i % channels) : moved(i)) changed.push_back(i);
    return changed;
}

std::uint64_t max_number(PointType type) {
    switch (type) {
        case PointType::boolean:
            return 1;
        case PointType::uint8:
            return 0xFF;
        case PointType::uint16:
            return 0xFFFF;
        case PointType::float32:
            break;
    }
    return 0;
}

Result<WritePlan> plan_point_write(std::optional<ModuleAddress> module, std::string_view id,
                                   std::uint64_t value) {
    const auto found = find_point(module ? std::optional(module->type) : std::nullopt, id);
    if (!found) return refused("no such point");
    const auto& spec = *found->spec;
    if (!spec.writable) return refused("an input: it cannot be set");
    if (value > max_number(spec.type))
        return refused(fmt::format("{} is over {}", value, max_number(spec.type)));
    WritePlan plan;
    if (!module) {  // the ID-2's reset
        plan.reset_counter = value != 0;
        return plan;
    }
    const auto v = static_cast<std::uint16_t>(value);
    OutputChange change{*module, 0xFFFF, v};
    if (id.starts_with("out") && spec.type == PointType::boolean) {
        const auto bit = static_cast<int>(found->index);  // out0 … out15 come first
        change.mask = static_cast<std::uint16_t>(1u << bit);
        change.value = static_cast<std::uint16_t>(v << bit);
    } else if (id == "pos") {
        change.mask = 0xFF00;
        change.value = static_cast<std::uint16_t>(v << 8);
    } else if (id == "neg") {
        change.mask = 0x00FF;
    }
    if (auto valid = validate_output_value(module->type, change.value); !valid)
        return refused(valid.error().message);
    plan.changes.push_back(change);
    return plan;
}

Result<std::uint64_t> parse_point_text(const PointSpec& point, std::string_view text) {
    const auto bad = [&](std::string_view allowed) {
        return refused(fmt::format("'{}' is not allowed: {}", printable(text, 40), allowed));
    };
    switch (point.type) {
        case PointType::boolean:
            if (const auto on = parse_switch(text)) return *on ? 1u : 0u;
            return bad("send ON or OFF (or 1/0, true/false)");
        case PointType::uint16:
            if (const auto n = parse_number(text, 0xFFFF)) return *n;
            return bad("send a number 0-65535 (or 0x0000-0xFFFF)");
        case PointType::uint8:
            if (point.id == "colour") {
                if (const auto colour = colour_from_name(text))
                    return std::uint64_t{static_cast<std::uint8_t>(*colour)};
                if (const auto n = parse_number(text, colour_count - 1)) return *n;
                return bad(
                    "send a colour: off, red, green, blue, cyan, magenta, yellow, white (or 0-7)");
            }
            if (const auto n = parse_number(text, mux_test_points - 1)) return *n;
            return bad("send a test point 0-7");
        case PointType::float32:
            break;
    }
    return refused("cannot be set");
}

std::string module_id(std::optional<ModuleAddress> module) {
    if (!module) return "id2";
    return fmt::format("{}_{}", name(module->type), module->number);
}

Result<WritePlan> plan_text_write(std::optional<ModuleAddress> module, std::string_view id,
                                  std::string_view text) {
    const auto refused = [&](std::string why) {
        return fail(Errc::invalid_argument,
                    fmt::format("{} {}: {}", module_id(module), printable(id, 40), why));
    };
    const auto found = find_point(module ? std::optional(module->type) : std::nullopt, id);
    if (!found) return refused("no such point");
    if (!found->spec->writable) return refused("an input: it cannot be set");
    if (text.size() > max_point_text)
        return refused(fmt::format("a value of {} bytes: at most {}", text.size(), max_point_text));
    const auto value = parse_point_text(*found->spec, text);
    if (!value) return refused(value.error().message);
    return plan_point_write(module, id, *value);
}

}  // namespace ioport::gateway
