// Names, units and scaling of a module's points (gateway.md §6.1): the one tag model that every
// northbound path renders, and the one function that turns a raw reading into the value it shows.
// Pure: the configuration loader resolves every default, the renderers only read.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "protocol/error.hpp"
#include "protocol/ioport.hpp"

namespace ioport::gateway {

inline constexpr std::size_t max_tag_bytes = 64;  // a name or a unit, in bytes of UTF-8

// scale: [in_lo, in_hi, out_lo, out_hi]; in_lo ≠ in_hi (the loader checks it).
struct Scale {
    double in_lo = 0;
    double in_hi = 0;
    double out_lo = 0;
    double out_hi = 0;
    friend bool operator==(const Scale&, const Scale&) = default;
};

// An analog channel, every default resolved.
struct ChannelTag {
    std::string name;               // "" when none is configured
    std::string unit;               // the unscaled unit by default, "" once a scale is set
    std::optional<Scale> scale;     // nullopt: the §2.1 value as it is
    std::array<double, 2> range{};  // lo < hi: [out_lo, out_hi] ordered, else [0, full scale]
    friend bool operator==(const ChannelTag&, const ChannelTag&) = default;
};

struct ModuleTags {
    std::string name;                      // "acm3p 0" unless configured
    std::vector<ChannelTag> channels;      // one per reply word of an analog module, else none
    std::array<std::string, 16> points{};  // dim16/lim16 inputs, dom16 outputs; "" = unnamed
    friend bool operator==(const ModuleTags&, const ModuleTags&) = default;
};

// The ID-2's: no module name of its own, no channels, no points.
extern const ModuleTags no_tags;

// Whether a module of this type has channels (analog) or named points (dim16, lim16, dom16).
bool has_channels(ModuleType type);
bool has_points(ModuleType type);

ModuleTags default_tags(ModuleAddress module);
ChannelTag default_channel(ModuleType type);
// The span a channel is expected to cover: [out_lo, out_hi] in order, else [0, full scale].
std::array<double, 2> default_range(ModuleType type, const std::optional<Scale>& scale);

// The engineering value of a channel: without a scale the vendor formula rounded once to float32
// (engineering_float, bit for bit); with one, that formula in double mapped linearly and rounded
// once. Not clamped: a reading outside [in_lo, in_hi] maps outside [out_lo, out_hi].
float channel_value(ModuleType type, std::uint16_t raw, const std::optional<Scale>& scale);
// The value of channel `channel` as `tags` scale it: unscaled where they have no such channel.
float channel_value(ModuleType type, std::uint16_t raw, const ModuleTags& tags,
                    std::size_t channel);
// As above, before the rounding to float32: the loader checks that a scale stays within float32.
double scaled(ModuleType type, std::uint16_t raw, const Scale& scale);

// A name or a unit: at most 64 bytes of valid UTF-8 with no control character (C0, DEL, C1);
// empty only where `may_be_empty`. The error says what is wrong, for a config error.
Result<> check_tag_text(std::string_view text, bool may_be_empty);

}  // namespace ioport::gateway
