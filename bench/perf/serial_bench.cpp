// Benchmark 1, serial overhead: how close the daemon's poll loop comes to what the pty and the
// simulator allow. ioport-sim answers at once (no line timing, no turnaround); in turns, on the
// same pty, a minimal raw client and ioportd each run the full bus's 48 reads back to back.
#include <algorithm>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"

namespace ioport::bench {
namespace {

struct Rate {
    double per_second = 0;
    double cpu_us = 0;  // CPU time per transaction, of ioportd
    std::uint64_t failed = 0;
};

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
                   fmt::format("{:.1f}", raw.cpu_us_per_transaction),
                   fmt::format("{:.1f}", daemon.cpu_us), fmt::format("{}", daemon.failed)});
        if (raw.failed > 0) fmt::print(stderr, "raw ping-pong: {} failed\n", raw.failed);
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
