#include "daemon/options.hpp"

#include <fmt/format.h>

namespace ioport::daemon {

const std::string_view usage =
    R"(Usage: ioportd [--config PATH] [--log-level LEVEL] [--log auto|stderr|journal]
       ioportd [--config PATH] --check-config
       ioportd [--config PATH] --print-map [--format md|csv]

Serves ioport remote I/O modules (hub8u/hub8r) and ID-2 stop/counter interfaces on serial links
as Modbus TCP units, as configured in one YAML file. Runs in the foreground until SIGTERM or
SIGINT (which set the outputs as on_shutdown says and exit 0); SIGHUP re-reads the
configuration and applies it if it is valid, keeping the links and clients it does not change.

  -c, --config PATH      the configuration (default /etc/ioportd/ioportd.yaml)
      --check-config     validate the configuration, print a summary and exit: 0 valid, 1 not
      --print-map        print the Modbus map of the configuration and exit (opens no port)
      --format md|csv    of --print-map: a Markdown table (default) or CSV
      --log-level LEVEL  trace, debug, info, warn, error, critical or off; overrides the
                         configuration's log_level (default info)
      --log TARGET       auto (default): the journal when stderr is connected to it, as
                         under systemd, else stderr; stderr: stderr with timestamps;
                         journal: the systemd journal, with fields LINK, UNIT, MODULE, CLIENT
  -V, --version          print the version and exit
  -h, --help             this text

Exit status: 0 stopped by a signal or a check passed; 1 invalid configuration or the Modbus port
could not be bound; 2 bad command line.
)";

namespace {

Expected<Options, std::string> error(std::string message) {
    return Unexpected(std::move(message) + " (ioportd --help for usage)");
}

}  // namespace

Expected<Options, std::string> parse_options(std::span<const std::string_view> arguments) {
    Options options;
    bool format_given = false;
    for (std::size_t i = 0; i < arguments.size(); ++i) {
        const auto argument = arguments[i];
        const auto value = [&]() -> std::optional<std::string_view> {
            if (i + 1 >= arguments.size()) return std::nullopt;
            return arguments[++i];
        };
        if (argument == "-c" || argument == "--config") {
            const auto path = value();
            if (!path || path->empty()) return error(fmt::format("{} needs a path", argument));
            options.config_path = std::string(*path);
        } else if (argument == "--check-config") {
            options.mode = Options::Mode::check_config;
        } else if (argument == "--print-map") {
            options.mode = Options::Mode::print_map;
        } else if (argument == "--format") {
            const auto format = value();
            if (format == "md" || format == "markdown")
                options.map_format = Options::MapFormat::markdown;
            else if (format == "csv")
                options.map_format = Options::MapFormat::csv;
            else
                return error("--format takes md or csv");
            format_given = true;
        } else if (argument == "--log-level") {
            const auto level = value();
            options.log_level = level ? config::log_level_from_name(*level) : std::nullopt;
            if (!options.log_level)
                return error("--log-level takes trace, debug, info, warn, error, critical or off");
        } else if (argument == "--log") {
            const auto target = value();
            if (target == "auto")
                options.log_target = Options::LogTarget::automatic;
            else if (target == "stderr")
                options.log_target = Options::LogTarget::standard_error;
            else if (target == "journal")
                options.log_target = Options::LogTarget::journal;
            else
                return error("--log takes auto, stderr or journal");
        } else if (argument == "-V" || argument == "--version") {
            options.mode = Options::Mode::version;
        } else if (argument == "-h" || argument == "--help") {
            options.mode = Options::Mode::help;
        } else {
            return error(fmt::format("unknown argument '{}'", argument));
        }
    }
    if (format_given && options.mode != Options::Mode::print_map)
        return error("--format is only for --print-map");
    return options;
}

}  // namespace ioport::daemon
