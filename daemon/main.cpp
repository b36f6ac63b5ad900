// ioportd: load the configuration, start the links and the Modbus server on one io_context,
// run until SIGTERM or SIGINT, stop in reverse order.
#include <csignal>
#include <iostream>
#include <string_view>
#include <vector>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "config/gateway_config.hpp"
#include "daemon/gateway.hpp"
#include "daemon/options.hpp"
#include "daemon/service_notifier.hpp"

namespace {

using ioport::daemon::Options;

// A graceful stop lets every coroutine finish; this bounds it should a device hold one up.
constexpr auto stop_deadline = std::chrono::milliseconds(1500);

void set_up_logging(const std::string& level) {
    auto logger = spdlog::stderr_color_st("ioportd");
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
    spdlog::set_default_logger(logger);
    spdlog::set_level(spdlog::level::from_str(level));
}

std::optional<ioport::config::GatewayConfig> load(const std::string& path) {
    auto loaded = ioport::config::load_config(path);
    if (loaded) return std::move(*loaded);
    for (const auto& error : loaded.error())
        std::cerr << to_string(error) << "\n";
    std::cerr << "ioportd: " << loaded.error().size() << " error(s) in " << path
              << "; nothing was started\n";
    return std::nullopt;
}

int print_map(const ioport::config::GatewayConfig& config, Options::MapFormat format) {
    std::vector<ioport::gateway::MapRow> rows;
    for (const auto& link : config.links) {
        ioport::gateway::UnitMap unit{link.protocol == ioport::config::Protocol::id2
                                          ? ioport::gateway::UnitKind::id2
                                          : ioport::gateway::UnitKind::ioport,
                                      link.unit_id,
                                      link.name,
                                      {}};
        for (const auto& module : link.modules)
            unit.modules.push_back(module.address);
        auto unit_rows = ioport::gateway::map_rows(unit);
        rows.insert(rows.end(), unit_rows.begin(), unit_rows.end());
    }
    std::cout << (format == Options::MapFormat::csv ? ioport::gateway::format_csv(rows)
                                                    : ioport::gateway::format_markdown(rows));
    return 0;
}

int run(ioport::config::GatewayConfig config) {
    asio::io_context io(1);
    ioport::daemon::Gateway gateway(io.get_executor(), std::move(config));
    if (auto started = gateway.start(); !started) {
        spdlog::critical("{}", started.error().message);
        gateway.stop();
        io.run_for(stop_deadline);
        return 1;
    }
    spdlog::info("ioportd {} started: {}", IOPORTD_VERSION, gateway.summary());
    ioport::daemon::ServiceNotifier service(
        io.get_executor(), [&] { return gateway.summary(); }, [&] { return gateway.healthy(); });
    service.ready();
    asio::signal_set signals(io, SIGINT, SIGTERM);
    signals.async_wait([&](const boost::system::error_code& ec, int signal) {
        if (ec) return;
        spdlog::info("{}: stopping", signal == SIGINT ? "SIGINT" : "SIGTERM");
        service.stopping();
        gateway.stop();
    });
    io.run();
    spdlog::info("ioportd stopped");
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<std::string_view> arguments(argv + 1, argv + argc);
    const auto options = ioport::daemon::parse_options(arguments);
    if (!options) {
        std::cerr << "ioportd: " << options.error() << "\n";
        return 2;
    }
    switch (options->mode) {
        case Options::Mode::help:
            std::cout << ioport::daemon::usage;
            return 0;
        case Options::Mode::version:
            std::cout << "ioportd " << IOPORTD_VERSION << "\n";
            return 0;
        default:
            break;
    }
    set_up_logging(options->log_level);
    auto config = load(options->config_path);
    if (!config) return 1;
    if (options->mode == Options::Mode::check_config) {
        std::cout << options->config_path << ": valid\n" << ioport::daemon::describe(*config);
        return 0;
    }
    if (options->mode == Options::Mode::print_map) return print_map(*config, options->map_format);
    return run(std::move(*config));
}
