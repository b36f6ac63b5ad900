// ioportd's command line, parsed without side effects.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "config/gateway_config.hpp"
#include "protocol/expected.hpp"

namespace ioport::daemon {

inline constexpr std::string_view default_config_path = "/etc/ioportd/ioportd.yaml";

struct Options {
    enum class Mode { run, check_config, print_map, version, help } mode = Mode::run;
    enum class MapFormat { markdown, csv } map_format = MapFormat::markdown;
    std::string config_path{default_config_path};
    // Where log lines go: the journal when stderr is connected to it (JOURNAL_STREAM), else
    // stderr with timestamps; or one of the two by choice.
    enum class LogTarget { automatic, standard_error, journal } log_target = LogTarget::automatic;
    // Given on the command line, it wins over the configuration's log_level.
    std::optional<config::LogLevel> log_level;
};

// argv without the program name. The error is a one-line message for stderr.
Expected<Options, std::string> parse_options(std::span<const std::string_view> arguments);

extern const std::string_view usage;

}  // namespace ioport::daemon
