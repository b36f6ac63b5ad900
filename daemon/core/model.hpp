// The one read model: what the core knows of each configured module (the bus, core/bus.hpp,
// tells what changes). Every transport renders this — the Modbus server its register image, the
// HTTP side its pages, the Sparkplug node its metrics — and none keeps a second copy of a
// module's values or status. Only the gateway's vocabulary (protocol/gateway_map.hpp: statuses,
// write plans) is shared with the Modbus map; nothing here knows a register or a topic.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "daemon/core/poll_plan.hpp"  // Clock
#include "daemon/core/trend.hpp"
#include "link/serial_link.hpp"
#include "protocol/gateway_map.hpp"
#include "protocol/points.hpp"

namespace ioport::daemon {

// A configured module as the core last saw it. The values are the last good ones, however old:
// status() and `last_good` say whether they are still current.
struct ModuleState {
    std::string name;                        // "dim16 0", "ID-2"
    std::optional<ModuleAddress> address{};  // nullopt: the ID-2
    int slot = 0;
    // The unit's status of every slot, the one place a module's status is held (the Modbus
    // map's planner reads it there); never null.
    const gateway::UnitState* unit = nullptr;
    gateway::ModuleStatus status() const { return unit->status[static_cast<std::size_t>(slot)]; }
    std::optional<Clock::time_point> last_good{};
    std::optional<Reading> reading{};       // input modules: the last good reading
    std::optional<std::uint16_t> output{};  // output modules: the state the device confirmed
    std::optional<bool> stop{};             // the ID-2's stop input
    std::optional<std::uint16_t> count{};   // the ID-2's counter
    const Trend* trend = nullptr;           // analog modules
    // Names, units and scales (gateway.md §6.1); never null. Every value shown anywhere is
    // gateway::channel_value(type, raw, tags->channels[c].scale).
    const gateway::ModuleTags* tags = &gateway::no_tags;
    // Its points' values (protocol/points.hpp), engineering values included: made once, when a
    // reading or a confirmed output is stored or the tags change, and rendered by every output.
    std::vector<std::optional<gateway::PointValue>> values{};
};

// "online", "no answer", "bad answer", "not polled yet", "not configured".
std::string_view status_text(gateway::ModuleStatus status);

// How a write ended: the result label of ioportd_writes_total and the audit's RESULT.
// `busy`: refused at once, max_pending_writes were waiting; `dropped`: still waiting when the
// communication-loss safe state was due (gateway.md §5.3). Neither sent anything.
enum class WriteResult { confirmed, error_ack, no_answer, link_down, busy, dropped };
inline constexpr std::size_t write_result_count = 6;
std::string_view to_string(WriteResult result);  // "confirmed", "error_ack", …

// Who asked for a write and what they asked, in their transport's own words: the audit record
// the core writes once the outcome is known, whichever path the write came by.
struct WriteOrigin {
    std::string client{};    // "10.0.0.5:50123", "sparkplug"
    std::string function{};  // "6", "DCMD": the audit's FUNCTION
    std::string address{};   // "1101", "hub0.dom16.0/out/3"
    std::string value{};     // "[1, 0]", "true"
    std::string request{};   // the audit line's words for it: "FC 06 address 1101 values [1]"
    Clock::time_point asked = Clock::now();
};

}  // namespace ioport::daemon
