// The points of a module: every value the gateway's outputs publish of it, in one order, by
// the ids of gateway.md §6.3, their values made from what the core read, and the one planner of a
// write to a point. Every output renders these: Sparkplug's metrics are the points under names of
// its own (out3 is out/3), the plain MQTT state document is them by id, and a write by DCMD, by a
// plain MQTT set or by HTTP is planned here. Pure.
//
//   dim16, lim16                  in0…in15 (boolean), word (uint16)
//   dom16                         out0…out15 (boolean, writable), word (uint16, writable)
//   acm3p, acm3c, dccim, dcvim    raw0…rawN-1 (uint16), then value0…valueN-1 (float32, the
//                                 engineering value of gateway.md §6.1)
//   rgbdm                         colour (uint8 0–7, writable)
//   mux8m                         pos, neg (uint8 0–7, writable)
//   the ID-2                      stop (boolean), count (uint16), reset (boolean, writable: a
//                                 command, not a state; always false)
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
#include "protocol/tags.hpp"

namespace ioport::gateway {

enum class PointType { boolean, uint8, uint16, float32 };

struct PointSpec {
    std::string id;
    PointType type = PointType::boolean;
    bool writable = false;
    bool command = false;  // the ID-2's reset: written, never a state
    friend bool operator==(const PointSpec&, const PointSpec&) = default;
};

// Every point of a module type, in order (nullopt: the ID-2): the same vector at every call.
const std::vector<PointSpec>& module_points(std::optional<ModuleType> type);
// The point `id` of a module type, and its place; nullopt when it has none of that id.
struct FoundPoint {
    const PointSpec* spec;
    std::size_t index;
};
std::optional<FoundPoint> find_point(std::optional<ModuleType> type, std::string_view id);

// What the core holds of a module: the raw words of an input module's last good reading, an
// output module's confirmed state, the ID-2's stop input and count.
struct ModuleReadings {
    std::optional<Reading> reading;
    std::optional<std::uint16_t> output;
    std::optional<bool> stop;
    std::optional<std::uint16_t> count;
};

// The values of module_points(type), in the same order, into `out` (its storage reused); nullopt
// where nothing was read yet. value<ch> is gateway::channel_value() with `tags`' scale, the one
// value every path shows.
void point_values(std::optional<ModuleType> type, const ModuleReadings& now, const ModuleTags& tags,
                  std::vector<std::optional<PointValue>>& out);

// The points whose value differs from the one last published (`published`, nullopt where none
// was), as indexes into module_points(type); except that an analog channel's raw<ch> and
// value<ch> go together, and only when the value moved more than `deadband` from the one last
// published (gateway.md §5.5), so that a noisy channel within the deadband publishes nothing and
// a slow drift goes out once it adds up.
std::vector<std::size_t> changed_points(std::optional<ModuleType> type,
                                        std::span<const std::optional<PointValue>> published,
                                        std::span<const std::optional<PointValue>> now,
                                        double deadband);

// The largest number a point of `type` takes: 1, 255, 65535 (a float32 takes none).
std::uint64_t max_number(PointType type);

// A write of `value` to point `id` as the gateway's one write path takes it: output changes
// (a dom16 bit or word, the rgbdm colour, mux8m pos or neg, merged into the desired state when
// sent) or the ID-2's counter reset (`reset_counter`; a reset of 0 plans nothing). Fails
// (invalid_argument) for a point the module does not have, an input, a value over the point's
// type, or one outside the module's own rule (validate_output_value, as for a Modbus write);
// never truncated. The message names no point: each output says it in its own words.
Result<WritePlan> plan_point_write(std::optional<ModuleAddress> module, std::string_view id,
                                   std::uint64_t value);

// A module in plain MQTT topics (gateway.md §6.3) and in HTTP writes (§7.1): "dim16_0"; the
// ID-2: "id2".
std::string module_id(std::optional<ModuleAddress> module);

// The longest text a write's value is read from; a longer one is refused unread.
inline constexpr std::size_t max_point_text = 32;

// A write of `text` to point `id`, as a plain MQTT set and an HTTP write ask for it:
// parse_point_text, then plan_point_write. Fails (invalid_argument, saying what is allowed and
// naming the module and point) for a point the module does not have or cannot write, and for any
// other text: never truncated, never guessed.
Result<WritePlan> plan_text_write(std::optional<ModuleAddress> module, std::string_view id,
                                  std::string_view text);

// A point's value in the words of a plain MQTT set (gateway.md §6.3) and of an HTTP write
// (§7.1): ON/OFF, 1/0, true/false for a boolean; a whole number, decimal or 0x hex, for a word;
// a colour name or 0–7 for colour; 0–7 for pos and neg. Fails saying what the point takes.
Result<std::uint64_t> parse_point_text(const PointSpec& point, std::string_view text);

}  // namespace ioport::gateway
