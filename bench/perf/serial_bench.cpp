// Benchmark 1, serial overhead: how close the daemon's poll loop comes to what the pty and the
// simulator allow. ioport-sim answers at once (no line timing, no turnaround); in turns, on the
// same pty, a minimal raw client and ioportd each run the full bus's 48 reads back to back.
#include <fcntl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"

namespace ioport::bench {
namespace {

std::chrono::nanoseconds thread_cpu_time() {
    timespec t{};
    ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return std::chrono::seconds(t.tv_sec) + std::chrono::nanoseconds(t.tv_nsec);
}

struct Rate {
    double per_second = 0;
    double cpu_us = 0;  // CPU time per transaction, of the raw client or of ioportd
    std::uint64_t failed = 0;
};

// The pty's own limit: blocking write() and read() until the CR, the same requests in the same
// order as the daemon's poll cycle, on the CPU the daemon gets.
Rate raw_ping_pong(const std::string& link, const std::vector<ModuleAddress>& modules,
                   std::chrono::milliseconds window, std::optional<int> cpu) {
    Rate rate;
    std::thread client([&] {
        pin_this_thread(cpu);
        const int fd = ::open(link.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
        if (fd < 0) return;
        termios tio{};
        ::tcgetattr(fd, &tio);
        ::cfmakeraw(&tio);
        tio.c_cc[VMIN] = 1;
        tio.c_cc[VTIME] = 0;
        ::tcsetattr(fd, TCSANOW, &tio);
        ::tcflush(fd, TCIOFLUSH);
        std::vector<std::string> requests;
        for (const auto module : modules)
            requests.push_back(encode_request(module).value());
        std::array<char, 64> buffer{};
        const auto transact = [&](const std::string& request) {
            if (::write(fd, request.data(), request.size()) != static_cast<ssize_t>(request.size()))
                return false;
            for (;;) {
                const auto n = ::read(fd, buffer.data(), buffer.size());
                if (n <= 0) return false;
                if (buffer[static_cast<std::size_t>(n) - 1] == '\r') return true;
            }
        };
        for (const auto& request : requests)  // a cycle to warm up
            transact(request);
        std::uint64_t done = 0;
        const auto cpu_before = thread_cpu_time();
        const auto start = Clock::now();
        const auto end = start + window;
        while (Clock::now() < end)
            for (const auto& request : requests) {
                if (!transact(request)) ++rate.failed;
                ++done;
            }
        const auto elapsed = seconds(Clock::now() - start);
        rate.per_second = static_cast<double>(done) / elapsed;
        rate.cpu_us = microseconds(thread_cpu_time() - cpu_before) / static_cast<double>(done);
        ::close(fd);
    });
    client.join();
    return rate;
}

Rate daemon_poll_loop(const Environment& env, const std::string& link,
                      const std::vector<ModuleAddress>& modules, std::chrono::milliseconds window) {
    TempDir dir;
    Gateway gateway(env, dir, gateway_yaml({{link, 115200, modules}}));
    Rate rate;
    if (!gateway.started() || !gateway.wait_until_polling()) return rate;
    ModbusConnection connection(gateway.port());
    const auto before = read_diagnostics(connection);
    const auto cpu_before = cpu_time(gateway.pid());
    const auto start = Clock::now();
    std::this_thread::sleep_for(window);
    const auto after = read_diagnostics(connection);
    const auto cpu_after = cpu_time(gateway.pid());
    const auto elapsed = seconds(Clock::now() - start);
    if (!before || !after) return rate;
    const auto done = after->ok - before->ok;
    rate.per_second = static_cast<double>(done) / elapsed;
    rate.cpu_us = microseconds(cpu_after - cpu_before) / static_cast<double>(std::max(done, 1U));
    rate.failed = after->failed - before->failed;
    gateway.stop();
    return rate;
}

}  // namespace

std::vector<Verdict> serial_overhead(const Environment& env) {
    fmt::print(
        "\n## 1. Serial overhead\n\nioport-sim with no line timing and no turnaround, full bus "
        "(48 reads). Raw ping-pong and ioportd take turns on the same pty, both on the server "
        "CPU.\n");
    TempDir dir;
    const auto modules = full_bus();
    SimProcess sim(env, dir / "tty", modules, {"--no-line-timing", "--turnaround", "0"});
    if (!sim.ready()) return {{"1. serial overhead", "simulator did not start", ">= 0.80", false}};
    const int rounds = env.quick ? 1 : 3;
    const auto window = env.window(3s);
    Table table({"round", "raw ping-pong tx/s", "ioportd tx/s", "ratio", "raw CPU µs/tx",
                 "ioportd CPU µs/tx", "ioportd failed tx"});
    std::vector<double> ratios, raws, daemons;
    for (int round = 1; round <= rounds; ++round) {
        const auto raw = raw_ping_pong(sim.link(), modules, window, env.placement.server_cpu);
        const auto daemon = daemon_poll_loop(env, sim.link(), modules, window);
        const double ratio = raw.per_second > 0 ? daemon.per_second / raw.per_second : 0;
        ratios.push_back(ratio);
        raws.push_back(raw.per_second);
        daemons.push_back(daemon.per_second);
        table.row({fmt::format("{}", round), fmt::format("{:.0f}", raw.per_second),
                   fmt::format("{:.0f}", daemon.per_second), fmt::format("{:.3f}", ratio),
                   fmt::format("{:.1f}", raw.cpu_us), fmt::format("{:.1f}", daemon.cpu_us),
                   fmt::format("{}", daemon.failed)});
    }
    const auto ratio = summarize(ratios).p50;
    const bool met = ratio >= 0.8;
    fmt::print("\nMedian ratio ioportd / raw ping-pong: **{:.3f}** (target >= 0.80: {})\n", ratio,
               yes_no(met));
    machine_line(fmt::format(
        R"({{"bench":"serial","raw_tps":{:.0f},"ioportd_tps":{:.0f},"ratio":{:.3f},"target":">=0.80","met":{}}})",
        summarize(raws).p50, summarize(daemons).p50, ratio, met));
    return {{"1. serial overhead", fmt::format("{:.3f} of raw ping-pong", ratio), ">= 0.80", met}};
}

}  // namespace ioport::bench
