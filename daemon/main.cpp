// ioportd: load the configuration, start the links and the Modbus server on one io_context,
// run until SIGTERM or SIGINT, stop in reverse order. SIGHUP re-reads the configuration.
#include <malloc.h>
#include <sys/stat.h>
#include <unistd.h>

#include <csignal>
#include <cstdlib>
#include <iostream>
#include <string_view>
#include <vector>

#include "config/check_text.hpp"
#include "config/gateway_config.hpp"
#include "daemon/base/log.hpp"
#include "daemon/gateway.hpp"
#include "daemon/http/render.hpp"
#include "daemon/options.hpp"
#include "daemon/service_notifier.hpp"

namespace {

using ioport::daemon::Log;
using ioport::daemon::Options;

// The orderly stop (writes in flight, outputs to `initial`) gets this long; then everything is
// cancelled, which leaves time to exit within the 2 s that gateway.md promises.
constexpr auto stop_deadline = std::chrono::milliseconds(1500);

Log::Target log_target(Options::LogTarget target) {
    switch (target) {
        case Options::LogTarget::journal:
            return Log::Target::journal;
        case Options::LogTarget::standard_error:
            return Log::Target::standard_error;
        case Options::LogTarget::automatic:
            break;
    }
    struct stat stderr_stat {};
    const bool journal = ::fstat(STDERR_FILENO, &stderr_stat) == 0 &&
                         ioport::daemon::is_journal_stream(std::getenv("JOURNAL_STREAM"),
                                                           stderr_stat.st_dev, stderr_stat.st_ino);
    return journal ? Log::Target::journal : Log::Target::standard_error;
}

// The YAML tree of a large configuration (names on every point of 8 links × 72 modules) takes
// megabytes while it is read; glibc keeps what was freed in the heap unless asked to give it
// back. Measured on that configuration: 6 MiB of RSS returned (bench/README.md, issue 27).
void return_parse_memory() {
    ::malloc_trim(0);
}

std::optional<ioport::config::GatewayConfig> load(const std::string& path) {
    auto loaded = ioport::config::load_config(path);
    return_parse_memory();
    if (loaded) return std::move(*loaded);
    for (const auto& error : loaded.error())
        std::cerr << to_string(error) << "\n";
    std::cerr << "ioportd: " << loaded.error().size() << " error(s) in " << path
              << "; nothing was started\n";
    return std::nullopt;
}

int print_map(const ioport::config::GatewayConfig& config, Options::MapFormat format) {
    std::cout << ioport::daemon::render_map(config, format == Options::MapFormat::csv
                                                        ? ioport::daemon::MapFormat::csv
                                                        : ioport::daemon::MapFormat::markdown);
    return 0;
}

// The daemon between start-up and exit: what the signals do.
class Daemon {
  public:
    Daemon(const Options& options, ioport::config::GatewayConfig config, Log& log)
        : options_(options),
          log_(log),
          gateway_(io_.get_executor(), std::move(config), log, disk_, hashing_),
          service_(
              io_.get_executor(), [this] { return gateway_.summary(); },
              [this] { return gateway_.healthy(); }, log),
          signals_(io_, SIGINT, SIGTERM, SIGHUP),
          deadline_(io_) {}

    int run() {
        if (auto started = gateway_.start(); !started) {
            log_.critical({}, "{}", started.error().message);
            gateway_.stop();
            io_.run_for(stop_deadline);
            return 1;
        }
        log_.info({}, "ioportd {} started: {}", IOPORTD_VERSION, gateway_.summary());
        service_.ready();
        wait_for_signal();
        io_.run();
        log_.info({}, "ioportd stopped");
        return 0;
    }

  private:
    void wait_for_signal() {
        signals_.async_wait([this](const boost::system::error_code& ec, int signal) {
            if (ec) return;
            if (signal == SIGHUP) {
                reload();
                wait_for_signal();
            } else {
                shut_down(signal);
            }
        });
    }

    void reload() {
        service_.reloading();
        const auto& path = options_.config_path;
        auto next = ioport::config::load_config(path);
        if (!next) {
            for (const auto& error : next.error())
                log_.error({}, "{}", to_string(error));
            auto text = fmt::format("SIGHUP: {} error(s) in {}; the running configuration is kept",
                                    next.error().size(), path);
            log_.error({}, "{}", text);
            gateway_.bus().publish(
                ioport::daemon::Note{.kind = ioport::daemon::EventKind::reload, .text = text});
        } else {
            const auto level = next->log_level;
            if (auto applied = gateway_.reload(std::move(*next)); !applied) {
                auto text = fmt::format("SIGHUP: {}; the running configuration is kept",
                                        applied.error().message);
                log_.error({}, "{}", text);
                gateway_.bus().publish(
                    ioport::daemon::Note{.kind = ioport::daemon::EventKind::reload, .text = text});
            } else {
                if (!options_.log_level) log_.set_level(level);
                log_.info({}, "SIGHUP: reloaded {}: {}", path, *applied);
            }
        }
        return_parse_memory();
        service_.ready();
    }

    void shut_down(int signal) {
        log_.info({}, "{}: stopping{}", signal == SIGINT ? "SIGINT" : "SIGTERM",
                  gateway_.config().on_shutdown == ioport::config::OnShutdown::initial
                      ? ", outputs to their initial values"
                      : "");
        service_.stopping();
        signals_.cancel();
        deadline_.expires_after(stop_deadline);
        deadline_.async_wait([this](const boost::system::error_code& ec) {
            if (ec) return;
            log_.warn({}, "stop: not finished within {} ms; the rest is abandoned",
                      stop_deadline.count());
            gateway_.stop();
        });
        gateway_.shut_down([this] { deadline_.cancel(); });
    }

    const Options& options_;
    Log& log_;
    // One thread does all the I/O, so Asio need not lock its reactor. The scheduler keeps its
    // lock: the serial ports' readers post their input here, the store's disk thread its
    // results, and Asio's resolver thread its answers. (Without it, such a post raced the loop: a
    // lost handler left forwarding unfinished and the loop's work count wrong, so that ioportd
    // never exited; benchmark 7f.)
    asio::io_context io_{BOOST_ASIO_CONCURRENCY_HINT_UNSAFE_IO};
    // Destroyed after the gateway, before the loop: the disk's finishes the stores' last syncs
    // (worker_thread.hpp).
    ioport::daemon::WorkerThread disk_;
    ioport::daemon::WorkerThread hashing_;
    ioport::daemon::Gateway gateway_;
    ioport::daemon::ServiceNotifier service_;
    asio::signal_set signals_;
    asio::steady_timer deadline_;
};

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
        case Options::Mode::check_config:
        case Options::Mode::print_map:
        case Options::Mode::run:
            break;  // they need the configuration
    }
    auto config = load(options->config_path);
    if (!config) return 1;
    switch (options->mode) {
        case Options::Mode::check_config:
            std::cout << options->config_path << ": valid\n"
                      << ioport::config::check_config_text(*config);
            return 0;
        case Options::Mode::print_map:
            return print_map(*config, options->map_format);
        case Options::Mode::run:
        case Options::Mode::help:
        case Options::Mode::version:
            break;
    }
    Log log(log_target(options->log_target), options->log_level.value_or(config->log_level));
    Daemon daemon(*options, std::move(*config), log);
    return daemon.run();
}
