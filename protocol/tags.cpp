#include "protocol/tags.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include <fmt/format.h>

#include "protocol/gateway_map.hpp"

namespace ioport::gateway {

const ModuleTags no_tags{};

bool has_channels(ModuleType type) {
    return engineering_unit(type) != Unit::none;
}

bool has_points(ModuleType type) {
    switch (type) {
        case ModuleType::dim16:
        case ModuleType::lim16:
        case ModuleType::dom16:
            return true;
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::dccim:
        case ModuleType::dcvim:
        case ModuleType::rgbdm:
        case ModuleType::mux8m:
            break;
    }
    return false;
}

std::array<double, 2> default_range(ModuleType type, const std::optional<Scale>& scale) {
    if (!scale) return {0.0, full_scale(type)};
    return {std::min(scale->out_lo, scale->out_hi), std::max(scale->out_lo, scale->out_hi)};
}

ChannelTag default_channel(ModuleType type) {
    return {.name = {},
            .unit = std::string(symbol(engineering_unit(type))),
            .scale = std::nullopt,
            .range = default_range(type, std::nullopt)};
}

ModuleTags default_tags(ModuleAddress module) {
    ModuleTags tags{.name = to_string(module), .channels = {}, .points = {}};
    if (has_channels(module.type))
        tags.channels.assign(static_cast<std::size_t>(reply_words(module.type)),
                             default_channel(module.type));
    return tags;
}

double scaled(ModuleType type, std::uint16_t raw, const Scale& scale) {
    const double unscaled = engineering_value(type, raw);
    return scale.out_lo +
           (unscaled - scale.in_lo) * (scale.out_hi - scale.out_lo) / (scale.in_hi - scale.in_lo);
}

float channel_value(ModuleType type, std::uint16_t raw, const std::optional<Scale>& scale) {
    if (!scale) return engineering_float(type, raw);
    return static_cast<float>(scaled(type, raw, *scale));
}

float channel_value(ModuleType type, std::uint16_t raw, const ModuleTags& tags,
                    std::size_t channel) {
    if (channel >= tags.channels.size()) return engineering_float(type, raw);
    return channel_value(type, raw, tags.channels[channel].scale);
}

Result<> check_tag_text(std::string_view text, bool may_be_empty) {
    const auto bad = [](std::string message) {
        return fail(Errc::invalid_argument, std::move(message));
    };
    if (text.empty() && !may_be_empty) return bad("must not be empty");
    if (text.size() > max_tag_bytes)
        return bad(
            fmt::format("is {} bytes long: at most {} bytes of UTF-8", text.size(), max_tag_bytes));
    for (std::size_t at = 0; at < text.size();) {
        const auto length = utf8_sequence(text.substr(at));
        if (length == 0) return bad(fmt::format("is not valid UTF-8 at byte {}", at));
        const auto lead = static_cast<unsigned char>(text[at]);
        const bool c1 = lead == 0xC2 && static_cast<unsigned char>(text[at + 1]) < 0xA0;
        if (lead < 0x20 || lead == 0x7F || c1)
            return bad(fmt::format("has a control character at byte {}", at));
        at += length;
    }
    return {};
}

}  // namespace ioport::gateway
