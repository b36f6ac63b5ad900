// Benchmark 5, footprint: ioportd's peak resident memory with eight links of 72 modules each (every
// type, 8 of each) and 256 clients, and its CPU time while it polls a full bus at 115200 baud
// with modelled line timing and no client is connected.
#include <memory>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"
#include "bench/perf/load.hpp"

namespace ioport::bench {
namespace {

struct Idle {
    double cpu_percent = 0;
    double cpu_us_per_tx = 0;
    double tx_per_second = 0;
};

// CPU time of ioportd over `window` while it polls and nothing else happens.
Idle idle(const Gateway& gateway, int units, std::chrono::milliseconds window) {
    std::vector<std::unique_ptr<ModbusConnection>> connections;
    std::vector<Diagnostics> before;
    for (int unit = 1; unit <= units; ++unit) {
        connections.push_back(std::make_unique<ModbusConnection>(gateway.port(), unit));
        before.push_back(read_diagnostics(*connections.back()).value_or(Diagnostics{}));
    }
    // The diagnostics connections stay open but silent: no client activity in the window.
    const auto cpu_before = cpu_time(gateway.pid());
    const auto start = Clock::now();
    std::this_thread::sleep_for(window);
    const auto cpu = cpu_time(gateway.pid()) - cpu_before;
    const auto elapsed = seconds(Clock::now() - start);
    std::uint64_t transactions = 0;
    for (int unit = 0; unit < units; ++unit) {
        const auto after = read_diagnostics(*connections[static_cast<std::size_t>(unit)]);
        if (after) transactions += after->ok - before[static_cast<std::size_t>(unit)].ok;
    }
    return {core_percent(cpu, elapsed),
            microseconds(cpu) / static_cast<double>(std::max<std::uint64_t>(transactions, 1)),
            static_cast<double>(transactions) / elapsed};
}

}  // namespace

std::vector<Verdict> footprint(const Environment& env) {
    fmt::print(
        "\n## 5. Footprint\n\nSimulators with modelled line timing at 115200 baud, turnaround 0, "
        "on the client CPU; ioportd on the server CPU.\n");
    std::vector<Verdict> verdicts;
    Table table({"setup", "RSS MiB", "peak RSS (VmHWM) MiB", "CPU (% of one core)",
                 "CPU µs/serial tx", "serial tx/s"});

    // Idle: one full bus, no clients.
    {
        TempDir dir;
        SimProcess sim(env, dir / "tty", full_bus(), {"--baud", "115200", "--turnaround", "0"});
        Gateway gateway(env, dir, gateway_yaml({{dir / "tty", 115200, full_bus()}}));
        if (sim.ready() && gateway.started() && gateway.wait_until_polling()) {
            std::this_thread::sleep_for(env.quick ? 100ms : 1s);
            const auto cpu = idle(gateway, 1, env.window(20s));
            const auto m = memory(gateway.pid());
            table.row(
                {"1 link, full bus (48 reads), no clients", fmt::format("{:.1f}", mib(m.rss_kib)),
                 fmt::format("{:.1f}", mib(m.peak_kib)), fmt::format("{:.2f} %", cpu.cpu_percent),
                 fmt::format("{:.1f}", cpu.cpu_us_per_tx),
                 fmt::format("{:.0f}", cpu.tx_per_second)});
            machine_line(fmt::format(
                R"({{"bench":"idle_cpu","links":1,"cpu_percent":{:.3f},"cpu_us_per_tx":{:.2f},"tx_per_s":{:.0f}}})",
                cpu.cpu_percent, cpu.cpu_us_per_tx, cpu.tx_per_second));
            // The floor, as in benchmark 2: a blocking write()/read() loop polling the same bus on
            // the same simulator and CPU pays the same wake-up per transaction. The target (issue
            // 14): no more than it, since on a guest whose wake-ups cost more than the work no
            // poller of a full bus gets under the 2 % first asked.
            gateway.stop();
            const auto raw =
                raw_ping_pong(dir / "tty", full_bus(), env.window(10s), env.placement.server_cpu);
            const double raw_percent = raw.cpu_us_per_transaction * raw.per_second / 1e4;
            table.row({"the same bus polled by a raw blocking client", "", "",
                       fmt::format("{:.2f} %", raw_percent),
                       fmt::format("{:.1f}", raw.cpu_us_per_transaction),
                       fmt::format("{:.0f}", raw.per_second)});
            machine_line(fmt::format(
                R"({{"bench":"idle_cpu_raw_client","cpu_percent":{:.3f},"cpu_us_per_tx":{:.2f},"tx_per_s":{:.0f},"ioportd_ratio":{:.3f},"target":"ioportd<=1.0x raw","met":{}}})",
                raw_percent, raw.cpu_us_per_transaction, raw.per_second,
                cpu.cpu_percent / raw_percent, cpu.cpu_percent <= raw_percent));
            verdicts.push_back(
                {"5. CPU at idle, full bus 115200",
                 fmt::format("{:.2f} % of one core, {:.3f}× a raw blocking client ({:.2f} %)",
                             cpu.cpu_percent, cpu.cpu_percent / raw_percent, raw_percent),
                 "<= 1.0× raw client", cpu.cpu_percent <= raw_percent});
        } else {
            verdicts.push_back({"5. CPU at idle", "did not start", "<= 1.0× raw client", false});
        }
    }

    // Eight links of 72 modules, then 256 clients.
    TempDir dir;
    const auto modules = every_module();
    std::vector<std::unique_ptr<SimProcess>> sims;
    std::vector<LinkSpec> links;
    bool ready = true;
    for (int i = 0; i < 8; ++i) {
        const auto link = dir / fmt::format("tty{}", i);
        sims.push_back(std::make_unique<SimProcess>(
            env, link, modules, std::vector<std::string>{"--baud", "115200", "--turnaround", "0"}));
        ready = ready && sims.back()->ready();
        links.push_back({link, 115200, modules});
    }
    Gateway gateway(env, dir, gateway_yaml(links, 300));
    if (!ready || !gateway.started() || !gateway.wait_until_polling(8, 60s)) {
        verdicts.push_back({"5. peak RSS", "did not start", "<= 16 MiB", false});
        return verdicts;
    }
    const auto polling = idle(gateway, 8, env.window(5s));
    const auto before = memory(gateway.pid());
    table.row({"8 links × 72 modules, no clients", fmt::format("{:.1f}", mib(before.rss_kib)),
               fmt::format("{:.1f}", mib(before.peak_kib)),
               fmt::format("{:.2f} %", polling.cpu_percent),
               fmt::format("{:.1f}", polling.cpu_us_per_tx),
               fmt::format("{:.0f}", polling.tx_per_second)});
    Memory during;
    const auto load = run_load({gateway.port(),
                                gateway.pid(),
                                256,
                                Mix::mixed,
                                8,
                                env.quick ? 100ms : 500ms,
                                env.window(4s),
                                [&] { during = memory(gateway.pid()); },
                                {}});
    const auto after = memory(gateway.pid());
    table.row({fmt::format("8 links × 72 modules, 256 clients ({:.0f} req/s, 1 in 16 writing)",
                           load.per_second()),
               fmt::format("{:.1f}", mib(during.rss_kib)),
               fmt::format("{:.1f}", mib(after.peak_kib)),
               fmt::format("{:.0f} %", load.cpu_percent()), "", ""});
    const bool met = load.connected && after.peak_kib <= std::size_t{16} * 1024;
    machine_line(fmt::format(
        R"({{"bench":"footprint","links":8,"modules_per_link":72,"clients":256,"rss_idle_mib":{:.2f},"rss_loaded_mib":{:.2f},"peak_rss_mib":{:.2f},"requests_per_s":{:.0f},"errors":{},"target":"<=16MiB","met":{}}})",
        mib(before.rss_kib), mib(during.rss_kib), mib(after.peak_kib), load.per_second(),
        load.errors, met));
    verdicts.push_back({"5. peak RSS, 8 links, 256 clients",
                        fmt::format("{:.1f} MiB", mib(after.peak_kib)), "<= 16 MiB", met});
    return verdicts;
}

}  // namespace ioport::bench
