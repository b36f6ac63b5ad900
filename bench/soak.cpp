// ioportd-soak: runs ioport-sim and ioportd for a given time with 64 Modbus clients reading and
// writing (bench/workload.hpp, every answer checked against the simulator's history) while the
// simulator injects faults: random serial faults on 1-10 % of transactions, an unplug now and
// then, a module going silent for a while, and SCADA falling silent with writes in flight
// (every client stops for longer than modbus.comm_loss_timeout while dom16 1 answers slowly, so
// its coil writes queue; every other time the port is also unplugged during the loss). Restarts
// ioportd if it dies (and counts it). Prints a table and one machine-readable line; exits 0 when
// nothing wrong was served, no write was lost and ioportd never died.
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "bench/workload.hpp"
#include "config/duration.hpp"
#include "sim/control_client.hpp"
#include "tests/support/beside_program.hpp"

extern char** environ;

namespace {

using ioport::bench::Clock;
using namespace std::chrono_literals;

constexpr std::string_view usage = R"(Usage: ioportd-soak [OPTIONS]

Runs ioport-sim and ioportd for DURATION with Modbus clients reading and writing while the
simulator injects faults and the clients fall silent past the comm-loss timeout now and then
(outputs to their safe state, gateway.md 5.3), checks every answer against the simulator's history, and prints what
was served, what went wrong and how ioportd's memory grew. Exit status 0: no wrong value, no
lost write, no write answered without reaching the device or pushed after failing, ioportd
never died; 1 otherwise; 2 on bad usage.

  --duration DUR     how long (default 60s; e.g. 10m)
  --clients N        Modbus clients (default 64)
  --pause DUR        a client's pause between requests, at random up to this (default 20ms)
  --seed N           of the clients, the faults and the simulator (default 1)
  --no-faults        no fault injection (a baseline)
  --ioportd PATH     the daemon (default: the one built beside this program)
  --sim PATH         the simulator (default: likewise)
  -h, --help         this text
)";

struct Options {
    std::chrono::microseconds duration = 60s;
    int clients = 64;
    std::chrono::microseconds pause = 20ms;
    std::uint64_t seed = 1;
    bool faults = true;
    std::string ioportd = IOPORTD_BINARY;
    std::string sim = IOPORT_SIM_BINARY;
};

std::optional<Options> parse(int argc, char** argv) {
    Options options;
    for (int i = 1; i < argc; ++i) {
        const std::string_view arg = argv[i];
        const auto value = [&]() -> std::optional<std::string_view> {
            if (i + 1 >= argc) return std::nullopt;
            return std::string_view(argv[++i]);
        };
        if (arg == "-h" || arg == "--help") {
            std::cout << usage;
            std::exit(0);
        }
        if (arg == "--no-faults") {
            options.faults = false;
            continue;
        }
        const auto text = value();
        if (!text) return std::nullopt;
        if (arg == "--duration" || arg == "--pause") {
            const auto duration = ioport::parse_duration(*text);
            if (!duration) return std::nullopt;
            (arg == "--duration" ? options.duration : options.pause) = *duration;
        } else if (arg == "--clients") {
            options.clients = std::atoi(std::string(*text).c_str());
            if (options.clients < 1 || options.clients > 512) return std::nullopt;
        } else if (arg == "--seed") {
            options.seed = std::strtoull(std::string(*text).c_str(), nullptr, 10);
        } else if (arg == "--ioportd") {
            options.ioportd = *text;
        } else if (arg == "--sim") {
            options.sim = *text;
        } else {
            return std::nullopt;
        }
    }
    return options;
}

// A child process with stdout and stderr in a log file; SIGTERM and reaped on destruction.
class Process {
  public:
    Process(const std::vector<std::string>& argv, const std::string& log) {
        const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0600);
        posix_spawn_file_actions_t actions;
        posix_spawn_file_actions_init(&actions);
        posix_spawn_file_actions_adddup2(&actions, fd, STDOUT_FILENO);
        posix_spawn_file_actions_adddup2(&actions, fd, STDERR_FILENO);
        std::vector<char*> args;
        args.reserve(argv.size() + 1);
        for (const auto& arg : argv)
            args.push_back(const_cast<char*>(arg.c_str()));
        args.push_back(nullptr);
        if (posix_spawn(&pid_, args[0], &actions, nullptr, args.data(), environ) != 0) pid_ = -1;
        posix_spawn_file_actions_destroy(&actions);
        ::close(fd);
    }
    ~Process() { stop(); }
    Process(const Process&) = delete;
    Process& operator=(const Process&) = delete;

    pid_t pid() const { return pid_; }
    // Still running? Reaps it when it is not.
    bool alive() {
        if (pid_ <= 0) return false;
        if (::waitpid(pid_, nullptr, WNOHANG) == 0) return true;
        pid_ = -1;
        return false;
    }
    void stop() {
        if (!alive()) return;
        ::kill(pid_, SIGTERM);
        for (int i = 0; i < 500 && alive(); ++i)
            std::this_thread::sleep_for(10ms);
        if (alive()) {
            ::kill(pid_, SIGKILL);
            ::waitpid(pid_, nullptr, 0);
        }
        pid_ = -1;
    }

  private:
    pid_t pid_ = -1;
};

// Polls `condition` every 10 ms until it holds or `deadline` passes.
template <class Condition>
bool wait_for(Condition condition, std::chrono::milliseconds deadline) {
    const auto until = Clock::now() + deadline;
    while (!condition()) {
        if (Clock::now() >= until) return false;
        std::this_thread::sleep_for(10ms);
    }
    return true;
}

std::uint16_t free_port() {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t length = sizeof address;
    const bool bound = ::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0 &&
                       ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) == 0;
    ::close(fd);
    return bound ? ntohs(address.sin_port) : 0;
}

bool accepts(std::uint16_t port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = htons(port);
    const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
    ::close(fd);
    return ok;
}

// VmRSS and VmHWM of a process, in kB.
std::pair<long, long> memory_kb(pid_t pid) {
    std::ifstream status(fmt::format("/proc/{}/status", pid));
    std::string line;
    long rss = 0;
    long peak = 0;
    while (std::getline(status, line)) {
        if (line.starts_with("VmRSS:")) rss = std::atol(line.c_str() + 6);
        if (line.starts_with("VmHWM:")) peak = std::atol(line.c_str() + 6);
    }
    return {rss, peak};
}

std::uint64_t total_injected(ioport::sim::ControlClient& control) {
    const auto text = control.command("faults");
    if (!text) return 0;
    std::istringstream words(*text);
    std::string kind;
    std::uint64_t count = 0;
    std::uint64_t total = 0;
    while (words >> kind >> count)
        total += count;
    return total;
}

}  // namespace

int main(int argc, char** argv) {
    const auto options = parse(argc, argv);
    if (!options) {
        std::cerr << "ioportd-soak: bad arguments\n" << usage;
        return 2;
    }
    std::string pattern = (std::filesystem::temp_directory_path() / "ioportd-soak-XXXXXX").string();
    if (::mkdtemp(pattern.data()) == nullptr) {
        std::perror("mkdtemp");
        return 1;
    }
    const std::filesystem::path dir = pattern;
    const auto link = (dir / "ttySIM").string();
    const auto control_path = (dir / "sim.ctl").string();
    const auto config_path = (dir / "ioportd.yaml").string();
    const auto port = free_port();
    if (port == 0) {
        std::perror("ioportd-soak: no free port on 127.0.0.1");
        return 1;
    }
    // A real line: 115200 baud, modelled, and the default timeout (100 ms). A shorter one
    // mistakes a simulator starved of CPU on a busy machine for a module answering two
    // timeouts late, which no master can tell from the next module's answer.
    constexpr auto timeout = 100ms;
    // Communication loss: 400 ms without a request. The readers among the clients ask every
    // 20 ms at most, so only the scenario's silences (and a machine that starves them all) get
    // there.
    constexpr auto comm_loss_timeout = 400ms;
    std::ofstream(config_path) << fmt::format(
        "modbus:\n  listen: \"127.0.0.1:{}\"\n  max_connections: {}\n  comm_loss_timeout: {}ms\n"
        "links:\n{}",
        port, options->clients + 16, comm_loss_timeout.count(),
        ioport::bench::hub_link_yaml(link, timeout, 1, 1000ms));

    Process sim({options->sim, "--link", link, "--control", control_path, "--hub",
                 ioport::bench::hub_sim_modules(), "--seed", std::to_string(options->seed)},
                (dir / "sim.log").string());
    // The socket file appears at bind(), a moment before the simulator listens: connect until
    // it answers.
    std::unique_ptr<ioport::sim::ControlClient> connected;
    if (!wait_for(
            [&] {
                connected = std::make_unique<ioport::sim::ControlClient>();
                return connected->connect(control_path).has_value();
            },
            10s)) {
        std::cerr << "ioportd-soak: the simulator did not start\n";
        return 1;
    }
    auto& control = *connected;
    const auto daemon_log = (dir / "ioportd.log").string();
    const auto start_daemon = [&] {
        auto daemon = std::make_unique<Process>(
            std::vector<std::string>{options->ioportd, "--config", config_path}, daemon_log);
        if (!wait_for([&] { return accepts(port) || !daemon->alive(); }, 10s) || !daemon->alive())
            return std::unique_ptr<Process>();
        return daemon;
    };
    auto daemon = start_daemon();
    if (!daemon) {
        std::cerr << "ioportd-soak: ioportd did not start; its log: " << daemon_log << "\n";
        return 1;
    }
    ioport::bench::WorkloadSettings settings;
    settings.port = port;
    settings.sim_control = control_path;
    settings.clients = options->clients;
    settings.pause = options->pause;
    settings.input_period = 100ms;
    settings.seed = options->seed;
    settings.timeout = timeout;
    settings.comm_loss_timeout = comm_loss_timeout;
    ioport::bench::Workload workload(settings);
    if (auto started = workload.start(); !started) {
        std::cerr << "ioportd-soak: " << started.error().message << "\n";
        return 1;
    }

    const auto started = Clock::now();
    const auto end = started + options->duration;
    // Memory once the clients are connected and the image is warm, and from then on.
    const auto warm_at = started + std::min<Clock::duration>(10s, options->duration / 10);
    long rss_warm = 0;
    long rss_last = 0;
    long rss_peak = 0;
    int restarts = 0;
    int unplugs = 0;
    int outages = 0;
    std::mt19937_64 random(options->seed);
    const std::vector<std::string> kinds{"silent", "error-ack", "garbage",
                                         "short",  "long",      "delay"};
    std::vector<std::string> modules;
    {
        std::istringstream list(ioport::bench::hub_sim_modules());
        std::string module;
        while (std::getline(list, module, ','))
            modules.push_back(module);
    }
    const auto between = [&](auto low, auto high) {
        return low + (high - low) * static_cast<long>(random() % 1000) / 1000;
    };
    auto next_faults = started;
    // The first unplug and outage early, so that a short run has them too.
    auto next_unplug = started + between(5s, 10s);
    auto next_outage = started + between(2s, 5s);
    std::optional<std::pair<std::string, Clock::time_point>> silent;
    // SCADA falling silent: dom16 1 is made slow first (answers 40 ms late, inside the 100 ms
    // timeout), so that the coil writes of 16 clients queue up and are in flight when every
    // client stops, and the loss is declared while they still drain. Every other time the port
    // is unplugged just after the loss was declared, and the silence lasts past a refresh after
    // the reopen, which must carry the safe values. The first early, so that a short run has a
    // few.
    const std::string slow_module = "dom16:1";
    auto next_silence = started + between(2s, 4s);
    std::optional<Clock::time_point> slowed;  // since then; the silence begins 300 ms later
    int silences = 0;
    int silences_failed = 0;
    int unplugs_during_loss = 0;
    std::vector<long long> silence_ms;
    auto next_report = started + 60s;
    while (Clock::now() < end) {
        const auto now = Clock::now();
        if (!daemon->alive()) {
            ++restarts;
            std::cerr << "ioportd-soak: ioportd died; restarting it\n";
            daemon = start_daemon();
            if (!daemon) break;
        }
        const auto [rss, peak] = memory_kb(daemon->pid());
        rss_last = rss;
        rss_peak = std::max(rss_peak, peak);
        if (rss_warm == 0 && now >= warm_at) rss_warm = rss;
        if (options->faults && now >= next_faults) {
            // Every module a new fault kind, on 1-10 % of its transactions. Late answers come
            // 1.5 timeouts after the request: late, yet inside the silence the link waits for.
            const auto late = fmt::format(" {}ms", (timeout * 3 / 2).count());
            for (const auto& module : modules) {
                if (silent && silent->first == module) continue;
                if (slowed && module == slow_module) continue;
                const auto& kind = kinds[random() % kinds.size()];
                const double probability =
                    0.01 + 0.09 * static_cast<double>(random() % 1000) / 1000;
                (void)control.command(fmt::format("fault {} {} {:.3f}{}", module, kind, probability,
                                                  kind == "delay" ? late : ""));
            }
            next_faults = now + 500ms;
        }
        if (options->faults && now >= next_unplug) {
            (void)control.command(fmt::format("unplug {}ms", between(1ms, 500ms).count()));
            ++unplugs;
            next_unplug = now + between(10s, 30s);
        }
        if (options->faults && !silent && now >= next_outage) {
            const auto& module = modules[random() % modules.size()];
            (void)control.command(fmt::format("fault {} silent", module));
            silent = {module, now + between(1s, 5s)};
            ++outages;
        }
        if (silent && now >= silent->second) {
            (void)control.command(fmt::format("fault {} none", silent->first));
            silent.reset();
            next_outage = now + between(15s, 40s);
        }
        if (options->faults && !slowed && now >= next_silence && now + 3s < end) {
            // A silent module stays silent: its writes queue anyway.
            if (!silent || silent->first != slow_module)
                (void)control.command(fmt::format("fault {} delay 40ms", slow_module));
            slowed = now;
        }
        if (slowed && now >= *slowed + 300ms) {
            const bool unplug = silences % 2 == 1;
            const auto length = unplug ? 1500ms : between(0ms, 300ms);
            const auto result = workload.silence(length, [&](Clock::time_point held) {
                if (!unplug) return;
                // The port lost while the safe push may still wait behind the queued writes:
                // the reopen must restore the safe state.
                const auto at = held + comm_loss_timeout + between(0ms, 200ms);
                while (Clock::now() < at)
                    std::this_thread::sleep_for(std::min<Clock::duration>(at - Clock::now(), 5ms));
                (void)control.command(fmt::format("unplug {}ms", between(50ms, 300ms).count()));
                ++unplugs_during_loss;
            });
            ++silences;
            if (result) {
                silence_ms.push_back(result->length.count());
            } else {
                ++silences_failed;
                std::cerr << "ioportd-soak: silence: " << result.error().message << "\n";
            }
            if (!silent || silent->first != slow_module)
                (void)control.command(fmt::format("fault {} none", slow_module));
            slowed.reset();
            next_silence = Clock::now() + between(4s, 7s);
        }
        if (now >= next_report) {
            const auto so_far = workload.snapshot();
            std::cerr << fmt::format(
                "ioportd-soak: {} s: {} requests checked, {} wrong values, {} lost writes, RSS "
                "{} kB\n",
                std::chrono::duration_cast<std::chrono::seconds>(now - started).count(),
                so_far.requests(), so_far.wrong_values, so_far.lost_writes, rss);
            next_report = now + 60s;
        }
        std::this_thread::sleep_for(50ms);
    }
    (void)control.command("fault all none");
    if (silent) (void)control.command(fmt::format("fault {} none", silent->first));
    const auto faults = total_injected(control) +
                        static_cast<std::uint64_t>(unplugs + outages + unplugs_during_loss);
    std::ranges::sort(silence_ms);
    const auto report = workload.finish();
    const auto elapsed = std::chrono::duration<double>(Clock::now() - started).count();
    const bool daemon_alive = daemon && daemon->alive();
    if (daemon) daemon->stop();
    sim.stop();

    const auto growth = rss_last - rss_warm;
    std::cout << fmt::format(
        "ioportd soak: {:.0f} s, {} clients, seed {}\n"
        "  requests served        {} ({:.0f}/s): reads {} (0B {}), writes {} (04 {}, 0B {})\n"
        "  faults injected        {} (serial faults, {} unplugs, {} module outages)\n"
        "  comm-loss episodes     {} (silences of {}-{} ms; {} with an unplug during the loss)\n"
        "    1020 after them      first request read 1: {}, the next 0: {}\n"
        "    writes in flight     {} when the clients fell silent\n"
        "    safe values seen     {} at the simulator (output modules, per episode); possible "
        "comm losses {}\n"
        "  wrong values served    {}\n"
        "  lost writes            {}\n"
        "  failed writes pushed   {}\n"
        "  unanswered requests    {} writes, {} transport errors\n"
        "  daemon restarts        {}\n"
        "  peak RSS               {} kB\n"
        "  RSS growth             {} kB (from {} kB after warm-up to {} kB)\n"
        "  read latency           p99 {:.1f} ms, max {:.1f} ms\n"
        "  write latency          p99 {:.1f} ms, max {:.1f} ms\n",
        elapsed, options->clients, options->seed, report.requests(),
        static_cast<double>(report.requests()) / elapsed, report.reads, report.reads_stale,
        report.writes, report.writes_04, report.writes_0b, faults, unplugs, outages, silences,
        silence_ms.empty() ? 0 : silence_ms.front(), silence_ms.empty() ? 0 : silence_ms.back(),
        unplugs_during_loss, report.silences_signalled, report.silences_cleared,
        report.writes_in_flight_at_silence, report.safe_pushes, report.possible_losses,
        report.wrong_values, report.lost_writes, report.failed_writes_pushed,
        report.unanswered_writes, report.transport_errors, restarts, rss_peak, growth, rss_warm,
        rss_last, std::chrono::duration<double, std::milli>(report.read_latency.p99).count(),
        std::chrono::duration<double, std::milli>(report.read_latency.max).count(),
        std::chrono::duration<double, std::milli>(report.write_latency.p99).count(),
        std::chrono::duration<double, std::milli>(report.write_latency.max).count());
    for (const auto& problem : report.problems)
        std::cout << "  problem: " << problem << "\n";
    std::cout << fmt::format(
        "SOAK seconds={:.0f} clients={} requests={} faults={} wrong_values={} lost_writes={} "
        "failed_writes_pushed={} unanswered_writes={} transport_errors={} restarts={} "
        "peak_rss_kb={} rss_growth_kb={} comm_loss_episodes={} comm_loss_signalled={} "
        "writes_in_flight_at_silence={} safe_pushes={}\n",
        elapsed, options->clients, report.requests(), faults, report.wrong_values,
        report.lost_writes, report.failed_writes_pushed, report.unanswered_writes,
        report.transport_errors, restarts, rss_peak, growth, silences, report.silences_signalled,
        report.writes_in_flight_at_silence, report.safe_pushes);
    const bool clean = report.wrong_values == 0 && report.lost_writes == 0 &&
                       report.failed_writes_pushed == 0 && report.unanswered_writes == 0 &&
                       report.unexpected_exceptions == 0 && restarts == 0 && daemon_alive &&
                       report.requests() > 0 && silences_failed == 0;
    std::error_code ignored;
    if (clean)
        std::filesystem::remove_all(dir, ignored);
    else
        std::cerr << "ioportd-soak: logs kept in " << dir.string() << "\n";
    return clean ? 0 : 1;
}
