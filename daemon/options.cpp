#include "daemon/options.hpp"

#include <array>

#include <fmt/format.h>

#include "config/command_line.hpp"

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

// The long options without a letter.
enum : int { check_config = 256, print_map, format, log_level, log_target };

constexpr std::array<option, 8> long_options{{
    {"config", required_argument, nullptr, 'c'},
    {"check-config", no_argument, nullptr, check_config},
    {"print-map", no_argument, nullptr, print_map},
    {"format", required_argument, nullptr, format},
    {"log-level", required_argument, nullptr, log_level},
    {"log", required_argument, nullptr, log_target},
    {"version", no_argument, nullptr, 'V'},
    {"help", no_argument, nullptr, 'h'},
}};

}  // namespace

Expected<Options, std::string> parse_options(std::span<const std::string_view> arguments) {
    Options options;
    bool format_given = false;
    CommandLine line("ioportd", arguments, "c:Vh", long_options);
    for (;;) {
        auto next = line.next();
        if (!next) return error(std::move(next).error());
        if (!*next) break;
        const auto& [code, value, name] = **next;
        switch (code) {
            case 'c':
                if (!value || value->empty()) return error(fmt::format("{} needs a path", name));
                options.config_path = std::string(*value);
                break;
            case check_config:
                options.mode = Options::Mode::check_config;
                break;
            case print_map:
                options.mode = Options::Mode::print_map;
                break;
            case format:
                if (value == "md" || value == "markdown")
                    options.map_format = Options::MapFormat::markdown;
                else if (value == "csv")
                    options.map_format = Options::MapFormat::csv;
                else
                    return error("--format takes md or csv");
                format_given = true;
                break;
            case log_level:
                options.log_level = value ? config::log_level_from_name(*value) : std::nullopt;
                if (!options.log_level)
                    return error(
                        "--log-level takes trace, debug, info, warn, error, critical or off");
                break;
            case log_target:
                if (value == "auto")
                    options.log_target = Options::LogTarget::automatic;
                else if (value == "stderr")
                    options.log_target = Options::LogTarget::standard_error;
                else if (value == "journal")
                    options.log_target = Options::LogTarget::journal;
                else
                    return error("--log takes auto, stderr or journal");
                break;
            case 'V':
                options.mode = Options::Mode::version;
                break;
            case 'h':
                options.mode = Options::Mode::help;
                break;
            default:  // a code of the table above without its case here
                return error(fmt::format("{} is not implemented", name));
        }
    }
    if (!line.operands().empty())
        return error(fmt::format("unknown argument '{}': ioportd takes only options",
                                 line.operands().front()));
    if (format_given && options.mode != Options::Mode::print_map)
        return error("--format is only for --print-map");
    return options;
}

}  // namespace ioport::daemon
