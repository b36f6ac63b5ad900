#include "config/loader.hpp"

#include <charconv>
#include <cmath>
#include <limits>

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 4> channel_keys{"name", "unit", "scale", "range"};

// A finite decimal number such as -20, 0.5 or 1e3.
Parsed<double> finite_number(const YAML::Node& value) {
    const std::string& text = value.Scalar();
    double number = 0;
    const auto* end = text.data() + text.size();
    const auto [at, ec] = std::from_chars(text.data(), end, number);
    if (quoted(value) || ec != std::errc() || at != end || !std::isfinite(number))
        return Unexpected(
            fmt::format("'{}' is not allowed: write a finite number such as -20 or 0.5, without "
                        "quotes",
                        printable(text, 40)));
    return number;
}

// A name or a unit (gateway.md §6.1).
auto tag_text(bool may_be_empty) {
    return [=](const YAML::Node& value) -> Parsed<std::string> {
        const std::string& text = value.Scalar();
        if (auto checked = gateway::check_tag_text(text, may_be_empty); !checked)
            return Unexpected(fmt::format("'{}' {}", printable(text, 80), checked.error().message));
        return text;
    };
}

}  // namespace

// Names, units and scales (gateway.md §6.1), every default resolved here.
void Loader::read_tags(const Fields& f, ModuleConfig& module) {
    const ModuleType type = module.address.type;
    module.tags = gateway::default_tags(module.address);
    read(f, "name", "a name such as \"boiler 1\"", module.tags.name, tag_text(false));
    if (const Entry* channels = f.find("channels")) {
        const auto count = module.tags.channels.size();
        if (count == 0) {
            add(channels->line, f.key("channels"),
                fmt::format("channels is for analog modules only (acm3p, acm3c, dccim, dcvim): "
                            "{} has none",
                            name(type)));
        } else {
            const auto have = count == 1 ? fmt::format("{} has channel 0 only", name(type))
                                         : fmt::format("{} has channels 0, 1 and 2", name(type));
            for (const auto& [index, entry] :
                 indexed(*channels, f.key("channels"), count, "channel", have))
                read_channel(entry, fmt::format("{}.{}", f.key("channels"), index), type,
                             module.tags.channels[index]);
        }
    }
    const bool inputs = type == ModuleType::dim16 || type == ModuleType::lim16;
    if (const Entry* entry = f.find("inputs")) {
        if (inputs)
            read_points(*entry, f.key("inputs"), type, module.tags.points);
        else
            add(entry->line, f.key("inputs"),
                fmt::format("inputs names the inputs of dim16 and lim16: {}",
                            type == ModuleType::dom16
                                ? "dom16 is an output module, name its outputs with outputs:"
                                : fmt::format("{} has no digital inputs", name(type))));
    }
    if (const Entry* entry = f.find("outputs")) {
        if (type == ModuleType::dom16)
            read_points(*entry, f.key("outputs"), type, module.tags.points);
        else
            add(entry->line, f.key("outputs"),
                fmt::format("outputs names the outputs of dom16: {}",
                            inputs ? fmt::format("{} is an input module, name its inputs with "
                                                 "inputs:",
                                                 name(type))
                                   : fmt::format("{} has no digital outputs", name(type))));
    }
}

void Loader::read_channel(const Entry& entry, const std::string& path, ModuleType type,
                          gateway::ChannelTag& channel) {
    const auto f =
        mapping(entry, path, channel_keys,
                "{ name: \"supply temperature\", unit: \"°C\", scale: [0, 100, -20, 150] }");
    if (!f) return;
    read(*f, "name", "a name such as \"supply temperature\"", channel.name, tag_text(false));
    if (const auto scale = read_numbers(
            *f, "scale", 4, "[in_lo, in_hi, out_lo, out_hi], e.g. [0, 100, -20, 150]")) {
        const gateway::Scale s{(*scale)[0], (*scale)[1], (*scale)[2], (*scale)[3]};
        const auto bound = static_cast<double>(std::numeric_limits<float>::max());
        const auto fits = [&](std::uint16_t raw) {
            return std::abs(gateway::scaled(type, raw, s)) <= bound;
        };
        if (s.in_lo == s.in_hi)
            add(f->line_of("scale"), f->key("scale"),
                fmt::format("in_lo and in_hi must differ: both are {}", s.in_lo));
        else if (s.out_lo == s.out_hi)
            add(f->line_of("scale"), f->key("scale"),
                fmt::format("out_lo and out_hi must differ: the channel would always read {}",
                            s.out_lo));
        else if (!fits(0) || !fits(0xFFFF))
            add(f->line_of("scale"), f->key("scale"),
                "this scale maps the channel's readings beyond what a float32 register can hold");
        else
            channel.scale = s;
        channel.unit.clear();  // a scaled value is no longer in the unscaled unit
        channel.range = gateway::default_range(type, channel.scale);
    }
    read(*f, "unit", "a unit such as \"°C\", or \"\" for none", channel.unit, tag_text(true));
    if (const auto range = read_numbers(*f, "range", 2, "[lo, hi], e.g. [0, 6]")) {
        if ((*range)[0] < (*range)[1])
            channel.range = {(*range)[0], (*range)[1]};
        else
            add(f->line_of("range"), f->key("range"),
                fmt::format("[{}, {}]: lo must be less than hi", (*range)[0], (*range)[1]));
    }
}

// A flow list of `count` finite numbers, nullopt when the key is absent or wrong (reported).
std::optional<std::vector<double>> Loader::read_numbers(const Fields& f, std::string_view name,
                                                        std::size_t count,
                                                        std::string_view example) {
    const Entry* entry = f.find(name);
    if (entry == nullptr) return std::nullopt;
    if (!entry->value.IsSequence() || entry->value.size() != count) {
        add(entry->line, f.key(name),
            fmt::format("expected a list of {} numbers {}, found {}", count, example,
                        entry->value.IsSequence() ? fmt::format("{} items", entry->value.size())
                                                  : kind(entry->value)));
        return std::nullopt;
    }
    std::vector<double> numbers;
    for (const auto& item : entry->value) {
        auto number = item.IsScalar()
                          ? finite_number(item)
                          : Unexpected(fmt::format("expected a number, found {}", kind(item)));
        if (!number) {
            add(line_of(item), f.key(name), std::move(number).error());
            return std::nullopt;
        }
        numbers.push_back(*number);
    }
    return numbers;
}

void Loader::read_points(const Entry& entry, const std::string& key, ModuleType type,
                         std::array<std::string, 16>& points) {
    const bool inputs = type != ModuleType::dom16;
    for (const auto& [index, point] :
         indexed(entry, key, points.size(), inputs ? "input" : "output",
                 fmt::format("{} has {} 0..15", name(type), inputs ? "inputs" : "outputs"))) {
        const std::string path = fmt::format("{}.{}", key, index);
        if (!point.value.IsScalar()) {
            add(point.line, path,
                fmt::format("expected a name such as \"pump running\", found {}",
                            kind(point.value)));
            continue;
        }
        auto text = tag_text(false)(point.value);
        if (text)
            points[index] = *std::move(text);
        else
            add(point.line, path, std::move(text).error());
    }
}

// A mapping by index, such as `channels: { 0: ..., 2: ... }`: each index once, below `count`.
std::vector<std::pair<std::size_t, Entry>> Loader::indexed(const Entry& entry,
                                                           const std::string& key,
                                                           std::size_t count, std::string_view noun,
                                                           std::string_view have) {
    std::vector<std::pair<std::size_t, Entry>> items;
    if (!entry.value.IsMap()) {
        add(entry.line, key,
            fmt::format("expected a mapping by {} number such as {{ 0: ... }}, found {}", noun,
                        kind(entry.value)));
        return items;
    }
    std::map<std::size_t, int> first_line;
    for (const auto& pair : entry.value) {
        const int line = line_of(pair.first);
        const std::string text = pair.first.IsScalar() ? pair.first.Scalar() : "";
        const auto index = pair.first.IsScalar() && !quoted(pair.first)
                               ? parse_unsigned(text, count - 1)
                               : std::nullopt;
        if (!index) {
            add(line, key,
                fmt::format("'{}' is not a {} number: {}", printable(text, 40), noun, have));
            continue;
        }
        const auto [first, fresh] = first_line.try_emplace(*index, line);
        if (fresh)
            items.emplace_back(*index, Entry{pair.second, line});
        else
            add(line, fmt::format("{}.{}", key, *index),
                fmt::format("duplicate {}: {} {} is already given at line {}", noun, noun, *index,
                            first->second));
    }
    return items;
}

}  // namespace ioport::config::detail
