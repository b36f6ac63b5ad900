// Durations as the configuration and the tools write them: "500us", "100ms", "2s", "5m".
#pragma once

#include <chrono>
#include <string>
#include <string_view>

#include "protocol/error.hpp"

namespace ioport {

// A whole number followed by us, ms, s or m; a bare "0" is zero.
Result<std::chrono::microseconds> parse_duration(std::string_view text);
// The shortest exact spelling: 100ms, 2s, 1500us.
std::string format_duration(std::chrono::microseconds duration);

}  // namespace ioport
