// ioportd-bench: the benchmarks of issues 6, 16, 17 and 18, described with their results in
// bench/README.md. bench/perf/run builds and runs them all; this program runs one or all of them.
#include <unistd.h>

#include <csignal>
#include <cstdlib>
#include <iostream>
#include <optional>
#include <string_view>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"
#include "bench/perf/load.hpp"
#include "bench/perf/tls_client.hpp"

namespace {

constexpr std::string_view usage = R"(Usage: ioportd-bench [OPTIONS] [BENCHMARK...]

Benchmarks ioportd against the physical limits (bench/README.md). BENCHMARK: serial, scan,
write, modbus, footprint, http, scrape (6b-c alone), flood (6f alone), sparkplug (7a-i), fleet
(7c alone), outage (7d alone), crash (7e alone), backlog (7f alone), store (7g alone),
templates (7h alone), relay (7i alone), tls, mqtt_json (9), curve (10: 1 to 16 links with every path on), or all
(the default).
Prints Markdown tables, a "BENCH {json}" line per figure and a summary of every figure against
its target. Asserts nothing: exit status 0 unless a program could not be started.

  --quick           every phase a fraction of a second: checks that everything runs, the
                    figures mean nothing
  --scale X         multiply every measured window by X (default 1)
  --ioportd PATH    the ioportd to measure (default: the one built beside this program)
  --baseline PATH   benchmarks 4, 6b, 6f and 7b also measure this ioportd (an earlier build)
                    in the same run: 4 in the same alternating rounds (CPU per request and rate
                    against it), 6b its CPU per scrape right after, 6f its rounds right after,
                    7b its CPU with MQTT on over the same windows
  --links N,M,...   benchmark 10's sizes, a row each (default 1,2,4,8,16; --quick: 1,2)
  --no-pin          do not pin servers and clients to CPUs 1 and 0
  --no-latency-hold let idle CPUs halt during benchmarks 1-4 as well (see WakeupLatencyHold
                    in harness.hpp): their figures then include the hypervisor's wake-ups
  --fill-trends     benchmark 6 waits 10 minutes for every trend ring to fill and measures
                    the memory then (otherwise it computes it)
  --fleet N         benchmarks 7c and 7f run N edge nodes on one broker (default 50; 0: skip
                    them, which a --quick run always does)
  --mosquitto PATH  the MQTT broker of benchmark 7 (default /usr/sbin/mosquitto; without
                    one, benchmark 7 says so and is skipped)

       ioportd-bench load PORT CONNECTIONS SECONDS [reads|writes|mixed] [TLS OPTIONS]
The load client of benchmark 4 alone, against a server started by hand (for profiling it
with perf, strace or callgrind): requests/s and latency percentiles. Over Modbus/TCP Security,
as benchmark 8's client:

  --tls CA CERT KEY the server's CA, the client's certificate and key (PEM files); PORT is
                    then the TLS listener's
  --tls1.2          TLS 1.2 only, without tickets (session ids); otherwise TLS 1.3
  --reconnect       a new connection for every request (connect, handshake, one request, close)
  --resume          with --reconnect: each connection resumes its thread's last session
)";

int load(int argc, char** argv) {
    using namespace ioport::bench;
    if (argc < 5) {
        std::cerr << usage;
        return 2;
    }
    const std::string_view mix = argc > 5 && argv[5][0] != '-' ? argv[5] : "reads";
    LoadSpec spec;
    std::optional<TlsClientSettings> tls;
    for (int i = 5; i < argc; ++i) {
        const std::string_view arg = argv[i];
        if (arg == "--tls" && i + 3 < argc) {
            tls = TlsClientSettings{argv[i + 1], argv[i + 2], argv[i + 3]};
            i += 3;
        } else if (arg == "--tls1.2" && tls) {
            tls->version = TLS1_2_VERSION;
            tls->no_tickets = true;
        } else if (arg == "--reconnect") {
            spec.connection_per_request = true;
        } else if (arg == "--resume") {
            spec.resume = true;
        } else if (arg != mix) {
            std::cerr << "ioportd-bench load: unknown argument '" << arg << "'\n" << usage;
            return 2;
        }
    }
    std::optional<TlsClientContext> client;
    if (tls) {
        client.emplace(*tls);
        if (!client->ok()) {
            std::cerr << "ioportd-bench load: " << client->failure() << "\n";
            return 1;
        }
        spec.tls = &*client;
    }
    spec.port = static_cast<std::uint16_t>(std::atoi(argv[2]));
    spec.connections = std::atoi(argv[3]);
    spec.window = std::chrono::milliseconds(static_cast<long>(std::atof(argv[4]) * 1000));
    spec.mix = mix == "writes" ? Mix::writes : mix == "mixed" ? Mix::mixed : Mix::reads;
    spec.server = ::getpid();
    const auto result = run_load(spec);
    if (!result.connected) return 1;
    std::vector<double> latency(result.latency_us.begin(), result.latency_us.end());
    const auto s = summarize(std::move(latency));
    fmt::print(
        "{:.0f} req/s, {} errors, latency µs p50 {:.0f} p99 {:.0f} p99.9 {:.0f} max {:.0f}\n",
        result.per_second(), result.errors, s.p50, s.p99, s.p999, s.max);
    if (spec.connection_per_request)
        fmt::print("{} connections, {} of them resumed\n", result.connections, result.resumed);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    using namespace ioport::bench;
    // Before anything else uses OpenSSL: benchmark 8c counts what it allocates.
    (void)OpenSslAllocations::install();
    // A server that closes a TLS connection must fail the client's next write, not kill this
    // program: OpenSSL writes to its sockets with write(), which raises SIGPIPE.
    (void)std::signal(SIGPIPE, SIG_IGN);
    if (argc > 1 && std::string_view(argv[1]) == "load") return load(argc, argv);
    Environment env;
    std::vector<std::string_view> chosen;
    bool pin = true;
    bool hold = true;
    for (int i = 1; i < argc; ++i) {
        const std::string_view arg = argv[i];
        if (arg == "--quick") {
            env.quick = true;
        } else if (arg == "--no-pin") {
            pin = false;
        } else if (arg == "--no-latency-hold") {
            hold = false;
        } else if (arg == "--fill-trends") {
            env.fill_trends = true;
        } else if (arg == "--fleet" && i + 1 < argc) {
            env.fleet = std::atoi(argv[++i]);
        } else if (arg == "--links" && i + 1 < argc) {
            env.curve_links.clear();
            for (std::string_view list = argv[++i]; !list.empty();) {
                const auto comma = list.find(',');
                const int links = std::atoi(std::string(list.substr(0, comma)).c_str());
                if (links < 1 || links > 247) {
                    std::cerr << "ioportd-bench: --links takes numbers of links 1-247, as 1,4,16\n";
                    return 2;
                }
                env.curve_links.push_back(links);
                list =
                    comma == std::string_view::npos ? std::string_view{} : list.substr(comma + 1);
            }
        } else if (arg == "--mosquitto" && i + 1 < argc) {
            env.binaries.mosquitto = argv[++i];
        } else if (arg == "--scale" && i + 1 < argc) {
            env.scale = std::atof(argv[++i]);
        } else if (arg == "--ioportd" && i + 1 < argc) {
            env.binaries.ioportd = argv[++i];
        } else if (arg == "--baseline" && i + 1 < argc) {
            env.binaries.baseline = argv[++i];
        } else if (arg == "-h" || arg == "--help") {
            std::cout << usage;
            return 0;
        } else if (arg == "serial" || arg == "scan" || arg == "write" || arg == "modbus" ||
                   arg == "footprint" || arg == "http" || arg == "scrape" || arg == "flood" ||
                   arg == "sparkplug" || arg == "fleet" || arg == "outage" || arg == "crash" ||
                   arg == "backlog" || arg == "store" || arg == "templates" || arg == "relay" ||
                   arg == "tls" || arg == "mqtt_json" || arg == "curve" || arg == "all") {
            chosen.push_back(arg);
        } else {
            std::cerr << "ioportd-bench: unknown argument '" << arg << "'\n" << usage;
            return 2;
        }
    }
    if (chosen.empty()) chosen.push_back("all");
    if (pin && ::sysconf(_SC_NPROCESSORS_ONLN) >= 2) {
        env.placement = {1, 0};
        // This process (the clients, the in-process simulator) on the client CPU.
        pin_this_thread(env.placement.client_cpu);
    }
    const auto wanted = [&](std::string_view name) {
        return std::find(chosen.begin(), chosen.end(), name) != chosen.end() ||
               std::find(chosen.begin(), chosen.end(), "all") != chosen.end();
    };
    std::vector<Verdict> verdicts;
    const auto add = [&](std::vector<Verdict> more) {
        verdicts.insert(verdicts.end(), more.begin(), more.end());
    };
    {
        std::optional<WakeupLatencyHold> latency;
        if (hold && !env.quick) latency.emplace();
        fmt::print("\nBenchmarks 1-4, 6, 7a-b, 8 and 9 {}.\n",
                   !latency ? "with idle CPUs free to halt"
                   : latency->failure().empty()
                       ? "with idle CPUs polling (/dev/cpu_dma_latency held at 0)"
                       : fmt::format("with idle CPUs free to halt ({})", latency->failure()));
        if (wanted("serial")) add(serial_overhead(env));
        if (wanted("scan")) add(scan_cycle(env));
        if (wanted("write")) add(write_latency(env));
        if (wanted("modbus")) add(modbus_throughput(env));
        // Its Modbus part is benchmark 4's load, so under the same conditions; its scrapes'
        // CPU is not an idle figure.
        if (wanted("http")) add(http_cost(env));
        // 6b-c alone (`all` runs them within http).
        if (std::find(chosen.begin(), chosen.end(), "scrape") != chosen.end())
            add(http_scrape_cost(env));
        // 6f alone.
        if (std::find(chosen.begin(), chosen.end(), "flood") != chosen.end())
            add(http_flood_cost(env));
        // Latency and the Modbus load of benchmark 4 again, under the same conditions.
        if (wanted("sparkplug")) add(sparkplug_cost(env));
        // Benchmark 4's load again, over TLS and plain.
        if (wanted("tls")) add(tls_cost(env));
        // Benchmark 7b's measure, with plain MQTT beside the edge node.
        if (wanted("mqtt_json")) add(mqtt_json_cost(env));
    }
    if (wanted("footprint")) add(footprint(env));
    // Every path at once, 1 to 16 links: a deployment's CPU, measured as benchmark 5's, with the
    // CPUs free to halt.
    if (wanted("curve")) add(cost_curve(env));
    // The fleet's CPU is the CPU of nodes that mostly wait, as benchmark 5's idle figure.
    if (wanted("sparkplug") || wanted("fleet")) add(sparkplug_fleet(env));
    // A broker outage and the forwarding after it (issue 26).
    if (wanted("sparkplug") || wanted("outage")) add(sparkplug_outage(env));
    if (wanted("sparkplug") || wanted("crash")) add(sparkplug_outage_kill(env));
    if (wanted("sparkplug") || wanted("backlog")) add(sparkplug_backlog(env));
    if (wanted("sparkplug") || wanted("store")) add(sparkplug_full_store(env));
    if (wanted("sparkplug") || wanted("templates")) add(sparkplug_templates(env));
    if (wanted("sparkplug") || wanted("relay")) add(sparkplug_relay(env));

    fmt::print("\n## Summary{}\n", env.quick ? " (--quick: the figures mean nothing)" : "");
    Table summary({"benchmark", "figure", "target", "met"});
    bool all_met = true;
    for (const auto& v : verdicts) {
        summary.row({v.benchmark, v.figure, v.target, yes_no(v.met)});
        all_met = all_met && v.met;
    }
    fmt::print("\n{}\n", all_met ? "Every target met." : "Some targets missed.");
    machine_line(fmt::format(R"({{"bench":"summary","targets":{},"all_met":{}}})", verdicts.size(),
                             all_met));
    const bool ran = std::none_of(verdicts.begin(), verdicts.end(), [](const Verdict& v) {
        return v.figure.find("did not start") != std::string::npos;
    });
    return ran ? 0 : 1;
}
