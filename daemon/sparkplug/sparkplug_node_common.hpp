// What the edge node's two halves share (sparkplug_node.cpp: sessions, births, data and the
// store's forwarding; sparkplug_commands.cpp: what arrives from the broker): the names of the
// Node Control metrics, and small conversions. Internal to daemon/sparkplug.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <variant>

#include <fmt/format.h>

#include "protocol/error.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::daemon::sparkplug_node {

inline constexpr std::string_view rebirth_metric = "Node Control/Rebirth";
inline constexpr std::string_view next_server_metric = "Node Control/Next Server";

// Of a string from the broker, this much reaches a log line (escaped).
inline constexpr std::size_t shown_bytes = 64;

inline std::string shown(std::string_view text) {
    return printable(text, shown_bytes);
}

inline std::uint64_t now_ms() {
    return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                          std::chrono::system_clock::now().time_since_epoch())
                                          .count());
}

inline std::optional<ModuleType> type_of(const std::optional<ModuleAddress>& module) {
    return module ? std::optional(module->type) : std::nullopt;
}

// A metric's value for a log line; a string one escaped, as everything from the broker.
inline std::string value_text(const std::optional<sparkplug::Value>& value) {
    if (!value) return "null";
    return std::visit(
        [](const auto& v) -> std::string {
            using V = std::decay_t<decltype(v)>;
            if constexpr (std::is_same_v<V, bool>)
                return v ? "true" : "false";
            else if constexpr (std::is_same_v<V, std::string>)
                return shown(v);
            else
                return fmt::format("{}", v);
        },
        *value);
}

}  // namespace ioport::daemon::sparkplug_node
