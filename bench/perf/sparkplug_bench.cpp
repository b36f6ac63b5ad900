// Benchmark 7, what the Sparkplug B edge node costs (issue 17, gateway.md §5.5), against a local
// mosquitto and a subscriber in this process (libmosquitto, on a thread of its own):
// a. latency from an input change at the device to the DDATA carrying it at the subscriber,
//    against the poll cycle of a full bus at 115200 baud;
// b. with every analog value of a full bus changing all the time: ioportd's CPU with MQTT on
//    against the same ioportd with MQTT off, side by side on the same changing input, the DDATA
//    rate, and Modbus at 64 connections on the one against the other;
// c. a fleet: N ioportd (50 by default), each an edge node on its own small simulated bus, on one
//    broker: how long until every birth arrived, the data rate, the broker's and the nodes' CPU;
// d. a broker outage with the store (issue 26): recorded against forwarded, bytes, CPU, and live
//    latency while the backlog is forwarded;
// e. the same with ioportd killed (SIGKILL) in the middle of the outage and started again;
// f. the fleet of c, each node forwarding the backlog of one outage, all at once;
// g. a store full at the largest max_size allowed: the start-up, and Modbus while a reload opens
//    it again (issue 37: its scan once ran on the loop).
#include <unistd.h>

#include <csignal>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <fstream>
#include <latch>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <span>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"
#include "bench/perf/load.hpp"
#include "bench/perf/mqtt_broker.hpp"
#include "bench/process_io.hpp"
#include "config/gateway_config.hpp"
#include "daemon/sparkplug/store_files.hpp"
#include "protocol/sparkplug.hpp"
#include "protocol/store_segment.hpp"

namespace ioport::bench {
namespace {

constexpr std::string_view group = "bench";

std::string node_id(int i) {
    return fmt::format("node{}", i);
}

std::string mqtt_yaml(std::uint16_t broker_port, std::string_view node,
                      std::string_view group_id = group) {
    return fmt::format(
        "mqtt:\n  broker: \"mqtt://127.0.0.1:{}\"\n  group_id: {}\n  edge_node_id: {}\n",
        broker_port, group_id, node);
}

// --baseline's edge node publishes in a group of its own, which the tally does not count.
constexpr std::string_view baseline_group = "bench-baseline";

double ms(double us) {
    return us / 1000.0;
}

// What a subscriber to spBv1.0/bench/# counted: messages and bytes (topic and payload) by
// message type and node, births, and gaps in each node's seq (a message lost on the way).
class Tally {
  public:
    void add(const Received& message) {
        const auto topic = sparkplug::parse_topic(message.topic);
        if (!topic) return;
        const auto payload = sparkplug::decode(message.payload);
        const std::scoped_lock lock(mutex_);
        auto& node = nodes_[topic->node];
        ++messages_;
        bytes_ += message.topic.size() + message.payload.size();
        switch (topic->type) {
            case sparkplug::MessageType::nbirth:
                if (!node.nbirth) node.nbirth = message.at;
                node.seq.reset();
                ++births_;
                break;
            case sparkplug::MessageType::dbirth:
                ++node.dbirths;
                node.last_dbirth = message.at;
                break;
            case sparkplug::MessageType::ddata:
                ++ddata_;
                ddata_bytes_ += message.topic.size() + message.payload.size();
                break;
            default:
                break;
        }
        if (payload && payload->seq && topic->type != sparkplug::MessageType::ndeath) {
            if (node.seq && *payload->seq != (*node.seq + 1) % 256)
                lost_ += (*payload->seq + 256 - (*node.seq + 1) % 256) % 256;
            node.seq = *payload->seq;
        }
    }

    struct Counts {
        std::uint64_t messages = 0, bytes = 0, ddata = 0, ddata_bytes = 0, lost = 0, births = 0;
        Counts operator-(const Counts& o) const {
            return {messages - o.messages,       bytes - o.bytes, ddata - o.ddata,
                    ddata_bytes - o.ddata_bytes, lost - o.lost,   births - o.births};
        }
    };
    Counts counts() const {
        const std::scoped_lock lock(mutex_);
        return {messages_, bytes_, ddata_, ddata_bytes_, lost_, births_};
    }
    struct Node {
        std::optional<Clock::time_point> nbirth;
        int dbirths = 0;
        Clock::time_point last_dbirth{};
        std::optional<std::uint64_t> seq;
    };
    std::optional<Node> node(const std::string& id) const {
        const std::scoped_lock lock(mutex_);
        const auto found = nodes_.find(id);
        if (found == nodes_.end()) return std::nullopt;
        return found->second;
    }

  private:
    mutable std::mutex mutex_;
    std::map<std::string, Node, std::less<>> nodes_;
    std::uint64_t messages_ = 0, bytes_ = 0, ddata_ = 0, ddata_bytes_ = 0, lost_ = 0, births_ = 0;
};

// --- a. Latency of report by exception ----------------------------------------------------------

std::vector<Verdict> latency(const Environment& env) {
    const int changes = env.quick ? 5 : std::max(200, static_cast<int>(200 * env.scale));
    const auto bus = full_bus();
    const ModuleAddress target{ModuleType::dim16, 0};
    fmt::print(
        "\n### 7a. Input change → DDATA at a subscriber ({} changes)\n\nA full bus ({} modules) "
        "at 115200 baud, modelled line timing, simulated in this process; ioportd an edge node on "
        "a local mosquitto (client CPU), a subscriber to the DDATA of {} (libmosquitto, client "
        "CPU). At random moments 60–140 ms apart, dim16 0's word is set to a new value on the "
        "simulator's thread, which timestamps it; the subscriber timestamps the DDATA whose "
        "`word` carries it. \"Read\" is when the device answered the first read that carried "
        "the value (its request's arrival plus the modelled wire time, from the simulator's "
        "log): before it, the change waits for the poll; after it, ioportd, the broker and the "
        "subscriber.\n",
        changes, bus.size(), sparkplug::device_id("hub0", target));
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: benchmark 7 skipped.\n", broker.why());
        return {};
    }
    InProcessSim sim(dir / "tty", bus, timed_line(115200), env.placement.client_cpu);
    const auto device = sparkplug::device_id("hub0", target);
    std::mutex mutex;
    std::optional<std::uint64_t> word_alias;
    std::map<std::uint64_t, Clock::time_point> arrived;  // word → first DDATA carrying it
    int rebirths = 0;
    Subscriber subscriber(
        broker.port(),
        {sparkplug::topic(group, sparkplug::MessageType::dbirth, node_id(0), device),
         sparkplug::topic(group, sparkplug::MessageType::ddata, node_id(0), device)},
        [&](const Received& message) {
            const auto topic = sparkplug::parse_topic(message.topic);
            const auto payload = sparkplug::decode(message.payload);
            if (!topic || !payload) return;
            const std::scoped_lock lock(mutex);
            if (topic->type == sparkplug::MessageType::dbirth) {
                if (word_alias) ++rebirths;
                for (const auto& metric : payload->metrics)
                    if (metric.name == "word") word_alias = metric.alias;
            }
            for (const auto& metric : payload->metrics) {
                const bool word =
                    metric.name == "word" || (word_alias && metric.alias == word_alias);
                const auto* value =
                    metric.value ? std::get_if<std::uint64_t>(&*metric.value) : nullptr;
                if (word && value != nullptr) arrived.try_emplace(*value, message.at);
            }
        });
    Gateway gateway(env, dir,
                    gateway_yaml({{dir / "tty", 115200, bus}}, 32, false,
                                 mqtt_yaml(broker.port(), node_id(0))));
    if (!sim.ready() || !subscriber.ready() || !gateway.started() ||
        !gateway.wait_until_polling() ||
        !wait_for(
            [&] {
                const std::scoped_lock lock(mutex);
                return word_alias.has_value();
            },
            10s))
        return {{"7a. change → DDATA", "ioportd did not start", "", false}};

    std::this_thread::sleep_for(100ms);
    (void)sim.take_log();
    ModbusConnection diagnostics(gateway.port());
    const auto before = read_diagnostics(diagnostics);
    const auto start = Clock::now();
    std::mt19937 random(17);
    std::uniform_int_distribution<int> pause_us(60'000, 140'000);
    std::vector<std::pair<std::uint16_t, Clock::time_point>> applied;
    for (int i = 0; i < changes; ++i) {
        std::this_thread::sleep_for(std::chrono::microseconds(pause_us(random)));
        const auto word = static_cast<std::uint16_t>(0x1000 + i);
        applied.emplace_back(word, sim.set_values(target, {word}));
    }
    wait_for(
        [&] {
            const std::scoped_lock lock(mutex);
            return arrived.contains(applied.back().first);
        },
        1s);
    const auto after = read_diagnostics(diagnostics);
    const auto elapsed = Clock::now() - start;
    const auto log = sim.take_log();

    // The cycle: ioportd's count of cycles over the window, and from the simulator's log the time
    // between two requests to dim16 0.
    double cycle_us = 0;
    if (before && after && after->cycles > before->cycles)
        cycle_us = microseconds(elapsed) / static_cast<double>(after->cycles - before->cycles);
    std::vector<double> device_cycles;
    std::optional<Clock::time_point> previous;
    for (const auto& entry : log) {
        if (entry.request != "a0") continue;
        if (previous) device_cycles.push_back(microseconds(sim.at(entry) - *previous));
        previous = sim.at(entry);
    }
    const auto device_cycle = summarize(device_cycles);

    // A change that the next one replaced before a read of dim16 0 saw it (a cycle longer than
    // the pause, on a busy machine) was never the device's input to any read: not counted.
    // One that a read carried and no DDATA did is lost.
    std::vector<double> total, waiting, after_read;
    int unread = 0, missing = 0;
    {
        const std::scoped_lock lock(mutex);
        for (const auto& change : applied) {
            const auto word = change.first;
            const auto at = change.second;
            const auto read = std::find_if(log.begin(), log.end(), [&](const sim::LogEntry& e) {
                return e.request == "a0" && !e.answer.empty() &&
                       std::strtoul(e.answer.c_str(), nullptr, 16) == word;
            });
            if (read == log.end()) {
                ++unread;
                continue;
            }
            const auto found = arrived.find(word);
            if (found == arrived.end()) {
                ++missing;
                continue;
            }
            const auto answered =
                sim.at(*read) +
                wire_time(read->request.size() + 1 + read->answer.size() + 1, 115200);
            total.push_back(microseconds(found->second - at));
            waiting.push_back(microseconds(answered - at));
            after_read.push_back(microseconds(found->second - answered));
        }
    }
    const auto t = summarize(total);
    const auto w = summarize(waiting);
    const auto r = summarize(after_read);
    Table table({"", "p50 ms", "p99 ms", "max ms", "changes"});
    const auto row = [&](std::string_view what, const Summary& s) {
        table.row({std::string(what), fmt::format("{:.2f}", ms(s.p50)),
                   fmt::format("{:.2f}", ms(s.p99)), fmt::format("{:.2f}", ms(s.max)),
                   fmt::format("{}", s.count)});
    };
    row("**change → DDATA at the subscriber**", t);
    row("change → read (the wait for the poll)", w);
    row("read → DDATA at the subscriber (ioportd, broker, subscriber)", r);
    row("poll cycle at the device (dim16 0 to dim16 0)", device_cycle);
    const double allowed_us = cycle_us + 5000;
    fmt::print(
        "\nPoll cycle: {:.2f} ms from ioportd's cycle count over the window (register 1001, the "
        "last cycle: {:.1f} ms). {} change(s) replaced by the next before a read saw them; {} "
        "read and never published; {} rebirth(s) of the device meanwhile.\n",
        ms(cycle_us), after ? after->last_cycle_100us / 10.0 : 0.0, unread, missing, rebirths);
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_latency","changes":{},"received":{},"unread":{},"missing":{},"p50_ms":{:.3f},"p99_ms":{:.3f},"max_ms":{:.3f},"wait_p50_ms":{:.3f},"wait_p99_ms":{:.3f},"after_read_p50_ms":{:.3f},"after_read_p99_ms":{:.3f},"after_read_max_ms":{:.3f},"cycle_ms":{:.3f},"register_1001_ms":{:.1f}}})",
        changes, t.count, unread, missing, ms(t.p50), ms(t.p99), ms(t.max), ms(w.p50), ms(w.p99),
        ms(r.p50), ms(r.p99), ms(r.max), ms(cycle_us),
        after ? after->last_cycle_100us / 10.0 : 0.0));
    return {{"7a. input change → DDATA p99, full bus at 115200",
             fmt::format("{:.2f} ms (p50 {:.2f}; read → DDATA p99 {:.2f}); cycle {:.2f} ms; {} of "
                         "{} read, {} lost",
                         ms(t.p99), ms(t.p50), ms(r.p99), ms(cycle_us), changes - unread, changes,
                         missing),
             fmt::format("<= cycle + 5 ms ({:.2f} ms), none lost", ms(allowed_us)),
             missing == 0 && t.count > 0 && cycle_us > 0 && t.p99 <= allowed_us}};
}

// --- b. CPU of publication, and Modbus beside it ------------------------------------------------

std::vector<Verdict> publication_cost(const Environment& env) {
    const auto bus = full_bus();
    const auto analog = analog_of(bus);
    const auto period = 5ms;
    fmt::print(
        "\n### 7b. CPU of publication: every analog value changing\n\nTwo full buses at 115200 "
        "baud (modelled, simulated in this process), each with its {} analog modules' every "
        "channel moving every {} ms, so that every read of them is a new value. Two ioportd on "
        "the server CPU, one per bus: \"on\" an edge node on a local mosquitto (client CPU), "
        "\"off\" without `mqtt:`. Both run throughout: their CPU is measured over the same "
        "windows, and the Modbus load of benchmark 4 (64 connections, reads) goes to one and "
        "then the other in alternating rounds.\n",
        analog.size(), period.count());
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: benchmark 7 skipped.\n", broker.why());
        return {};
    }
    Tally tally;
    Subscriber subscriber(broker.port(), {fmt::format("spBv1.0/{}/#", group)},
                          [&](const Received& message) { tally.add(message); });
    InProcessSim sim_on(dir / "tty-on", bus, timed_line(115200), env.placement.client_cpu);
    InProcessSim sim_off(dir / "tty-off", bus, timed_line(115200), env.placement.client_cpu);
    TempDir dir_off;
    Gateway on(env, dir,
               gateway_yaml({{dir / "tty-on", 115200, bus}}, 300, false,
                            mqtt_yaml(broker.port(), node_id(0))));
    Gateway off(env, dir_off, gateway_yaml({{dir / "tty-off", 115200, bus}}, 300));
    // --baseline: the earlier ioportd, MQTT on, on the same broker and the same changing input,
    // over the same windows.
    std::optional<TempDir> dir_base;
    std::optional<InProcessSim> sim_base;
    std::optional<Gateway> base;
    if (!env.binaries.baseline.empty()) {
        dir_base.emplace();
        sim_base.emplace(*dir_base / "tty", bus, timed_line(115200), env.placement.client_cpu);
        base.emplace(env.baseline(), *dir_base,
                     gateway_yaml({{*dir_base / "tty", 115200, bus}}, 300, false,
                                  mqtt_yaml(broker.port(), node_id(0), baseline_group)));
        if (!sim_base->ready() || !base->started() || !base->wait_until_polling())
            return {{"7b. CPU of publication", "the baseline ioportd did not start", "", false}};
        sim_base->wander(analog, period);
    }
    if (!sim_on.ready() || !sim_off.ready() || !subscriber.ready() || !on.started() ||
        !off.started() || !on.wait_until_polling() || !off.wait_until_polling() ||
        !wait_for(
            [&] {
                const auto node = tally.node(node_id(0));
                return node && node->dbirths >= static_cast<int>(bus.size());
            },
            10s))
        return {{"7b. CPU of publication", "ioportd did not start", "", false}};
    sim_on.wander(analog, period);
    sim_off.wander(analog, period);
    std::this_thread::sleep_for(env.quick ? 100ms : 1s);

    // b1. CPU, both over the same windows.
    const int windows = env.quick ? 1 : 5;
    const auto window = env.window(3s);
    const Table cpu_table({"window", "ioportd on, CPU", "ioportd off, CPU", "on ÷ off", "DDATA/s",
                           "KiB/s at the subscriber", "broker CPU"});
    std::vector<double> ratios;
    std::vector<double> baseline_ratios;
    Tally::Counts total_counts, counts_before;
    std::vector<pid_t> pids{on.pid(), off.pid(), broker.pid()};
    if (base) pids.push_back(base->pid());
    const auto cpu = cpu_windows(
        pids, windows, window, [&](int) { counts_before = tally.counts(); },
        [&](int i, const std::vector<std::chrono::nanoseconds>& used, double s) {
            const auto counts = tally.counts() - counts_before;
            const double on_pct = core_percent(used[0], s);
            const double off_pct = core_percent(used[1], s);
            ratios.push_back(on_pct / off_pct);
            if (base)
                baseline_ratios.push_back(microseconds(used[0]) /
                                          std::max(microseconds(used[3]), 1.0));
            cpu_table.row({fmt::format("{}", i + 1), fmt::format("{:.2f} %", on_pct),
                           fmt::format("{:.2f} %", off_pct), fmt::format("{:.2f}", ratios.back()),
                           fmt::format("{:.0f}", static_cast<double>(counts.ddata) / s),
                           fmt::format("{:.1f}", static_cast<double>(counts.bytes) / 1024 / s),
                           fmt::format("{:.2f} %", core_percent(used[2], s))});
            total_counts.messages += counts.messages;
            total_counts.bytes += counts.bytes;
            total_counts.ddata += counts.ddata;
            total_counts.ddata_bytes += counts.ddata_bytes;
            total_counts.lost += counts.lost;
        });
    const double total_seconds = cpu.seconds;
    const double on_pct = cpu.percent(0);
    const double off_pct = cpu.percent(1);
    const double broker_pct = cpu.percent(2);
    const double ddata_per_s = static_cast<double>(total_counts.ddata) / total_seconds;
    const double us_per_ddata = microseconds(cpu.total[0] - cpu.total[1]) /
                                static_cast<double>(std::max<std::uint64_t>(total_counts.ddata, 1));
    const double cpu_ratio = median(ratios);
    fmt::print(
        "\nAll windows ({:.1f} s): ioportd {:.2f} % of a core with MQTT on, {:.2f} % off: "
        "{:.3f}× (median of the windows {:.3f}×); {:.0f} DDATA/s ({:.0f} B each with its topic), "
        "{:.1f} µs of ioportd's CPU per DDATA beyond polling; the broker {:.2f} %; {} lost "
        "(gaps in seq).\n",
        total_seconds, on_pct, off_pct, on_pct / off_pct, cpu_ratio, ddata_per_s,
        static_cast<double>(total_counts.ddata_bytes) /
            static_cast<double>(std::max<std::uint64_t>(total_counts.ddata, 1)),
        us_per_ddata, broker_pct, total_counts.lost);
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_cpu","analog_modules":{},"change_period_ms":{},"seconds":{:.2f},"cpu_on_pct":{:.3f},"cpu_off_pct":{:.3f},"ratio_total":{:.4f},"ratio_median":{:.4f},"ddata_per_s":{:.1f},"bytes_per_s":{:.0f},"us_per_ddata":{:.2f},"broker_cpu_pct":{:.3f},"lost":{}}})",
        analog.size(), period.count(), total_seconds, on_pct, off_pct, on_pct / off_pct, cpu_ratio,
        ddata_per_s, static_cast<double>(total_counts.bytes) / total_seconds, us_per_ddata,
        broker_pct, total_counts.lost));
    if (base) {
        const double base_pct = cpu.percent(3);
        fmt::print(
            "\nAgainst the baseline {} (MQTT on, the same input, the same windows): {:.2f} % ÷ "
            "{:.2f} % of a core = {:.3f}× (median of the windows {:.3f}×).\n",
            env.binaries.baseline, on_pct, base_pct, on_pct / base_pct, median(baseline_ratios));
        machine_line(fmt::format(
            R"({{"bench":"sparkplug_cpu_baseline","cpu_on_pct":{:.3f},"cpu_baseline_pct":{:.3f},"ratio_total":{:.4f},"ratio_median":{:.4f}}})",
            on_pct, base_pct, on_pct / base_pct, median(baseline_ratios)));
    }

    // b2. Modbus at 64 connections, on the one and then the other.
    constexpr int connections = 64;
    const int rounds = env.quick ? 1 : 7;
    const auto load_window = env.window(3s);
    fmt::print(
        "\n#### Modbus at {} connections, MQTT on against off ({} pairs of {} ms rounds, "
        "alternating)\n",
        connections, rounds, load_window.count());
    const Table rounds_table({"round", "ioportd", "req/s", "p99 µs", "server CPU µs/req", "errors",
                              "poll cycle ms", "DDATA/s meanwhile"});
    // The poll cycle of the loaded ioportd over its round, from its own counters: what the load
    // leaves of polling, and so of what there is to publish.
    ModbusConnection diagnostics_on(on.port()), diagnostics_off(off.port());
    Tally::Counts loaded;
    double loaded_seconds = 0;
    std::optional<Diagnostics> cycles_before;
    Clock::time_point round_start;
    const auto diagnostics = [&](int mqtt) -> ModbusConnection& {
        return mqtt ? diagnostics_on : diagnostics_off;
    };
    const auto rounds_run = alternating_rounds(
        {&off, &on}, connections, rounds, env.quick ? 100ms : 500ms, load_window,
        {.before =
             [&](int mqtt) {
                 counts_before = tally.counts();
                 cycles_before = read_diagnostics(diagnostics(mqtt));
                 round_start = Clock::now();
             },
         .after =
             [&](int round, int mqtt, const LoadResult& result, const Summary& latency,
                 double round_seconds) {
                 const auto counts = tally.counts() - counts_before;
                 const auto cycles_after = read_diagnostics(diagnostics(mqtt));
                 const double cycle_ms =
                     cycles_before && cycles_after && cycles_after->cycles > cycles_before->cycles
                         ? seconds(Clock::now() - round_start) * 1000 /
                               static_cast<double>(cycles_after->cycles - cycles_before->cycles)
                         : 0.0;
                 rounds_table.row(
                     {fmt::format("{}", round + 1), mqtt ? "on" : "off",
                      fmt::format("{:.0f}", result.per_second()),
                      fmt::format("{:.0f}", latency.p99),
                      fmt::format("{:.2f}", result.cpu_us_per_request()),
                      fmt::format("{}", result.errors), fmt::format("{:.1f}", cycle_ms),
                      mqtt
                          ? fmt::format("{:.0f}", static_cast<double>(counts.ddata) / round_seconds)
                          : std::string()});
                 if (mqtt) {
                     loaded.ddata += counts.ddata;
                     loaded.lost += counts.lost;
                     loaded_seconds += round_seconds;
                 }
             }});
    const auto& latency = rounds_run.latency;
    const auto& p99_ratios = rounds_run.p99_ratios;
    const auto& cpu_ratios = rounds_run.cpu_ratios;
    const auto& load_on = rounds_run.total[1];
    const auto& load_off = rounds_run.total[0];
    fmt::print("\nAll rounds together:\n");
    const Table table(
        {"ioportd", "req/s", "p50 µs", "p99 µs", "p99.9 µs", "server CPU µs/req", "errors"});
    for (const int mqtt : {0, 1}) {
        const auto& side = rounds_run.total[static_cast<std::size_t>(mqtt)];
        const auto& l = latency[static_cast<std::size_t>(mqtt)];
        table.row({mqtt ? "MQTT on" : "MQTT off", fmt::format("{:.0f}", side.per_second()),
                   fmt::format("{:.0f}", l.p50), fmt::format("{:.0f}", l.p99),
                   fmt::format("{:.0f}", l.p999), fmt::format("{:.2f}", side.cpu_us_per_request()),
                   fmt::format("{}", side.errors)});
    }
    const double p99_median = median(p99_ratios);
    const double cpu_median = median(cpu_ratios);
    const double p99_total = latency[1].p99 / latency[0].p99;
    fmt::print(
        "\nOn ÷ off: p99 median of {} pairs {:.3f}× (all rounds {:.3f}×), CPU per request "
        "{:.3f}× (all rounds {:.3f}×); {:.0f} DDATA/s published during the loaded rounds, {} "
        "lost.\n",
        rounds, p99_median, p99_total, cpu_median,
        load_on.cpu_us_per_request() / load_off.cpu_us_per_request(),
        static_cast<double>(loaded.ddata) / std::max(loaded_seconds, 1e-9), loaded.lost);
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_modbus","connections":{},"rounds":{},"req_s_on":{:.0f},"req_s_off":{:.0f},"p99_us_on":{:.0f},"p99_us_off":{:.0f},"p99_ratio_median":{:.4f},"p99_ratio_total":{:.4f},"cpu_us_on":{:.3f},"cpu_us_off":{:.3f},"cpu_ratio_median":{:.4f},"errors_on":{},"errors_off":{},"ddata_per_s":{:.1f},"lost":{}}})",
        connections, rounds, load_on.per_second(), load_off.per_second(), latency[1].p99,
        latency[0].p99, p99_median, p99_total, load_on.cpu_us_per_request(),
        load_off.cpu_us_per_request(), cpu_median, load_on.errors, load_off.errors,
        static_cast<double>(loaded.ddata) / std::max(loaded_seconds, 1e-9), loaded.lost));

    return {{"7b. ioportd CPU, MQTT on ÷ off, every analog value changing",
             fmt::format("{:.2f} % ÷ {:.2f} % = {:.3f}× (median of {} windows; {:.0f} DDATA/s, "
                         "{:.1f} µs each; broker {:.2f} %)",
                         on_pct, off_pct, on_pct / off_pct, windows, ddata_per_s, us_per_ddata,
                         broker_pct),
             "(reported), none lost", total_counts.lost == 0 && total_counts.ddata > 0},
            {"7b. Modbus p99 at 64 connections, MQTT on ÷ off",
             fmt::format("median of {} pairs {:.3f}× (all rounds: {:.0f} vs {:.0f} µs = {:.3f}×)",
                         rounds, p99_median, latency[1].p99, latency[0].p99, p99_total),
             "<= 1.05×", load_on.errors == 0 && load_off.errors == 0 && p99_median <= 1.05}};
}

// The fleet of 7c and 7f: each node's small bus, read every fleet_poll, every input changing
// every fleet_period, so that every read is published.
const std::vector<ModuleAddress> fleet_bus{
    {ModuleType::dim16, 0}, {ModuleType::acm3p, 0}, {ModuleType::acm3c, 0}, {ModuleType::dccim, 0}};
constexpr auto fleet_poll = 100ms;
constexpr auto fleet_period = 20ms;

// The CPU time of every ioportd of a fleet, together.
std::chrono::nanoseconds cpu_time_of(const std::vector<std::unique_ptr<Gateway>>& gateways) {
    std::chrono::nanoseconds total{};
    for (const auto& gateway : gateways)
        total += cpu_time(gateway->pid());
    return total;
}

// --- c. A fleet on one broker
// ---------------------------------------------------------------------

std::vector<Verdict> fleet(const Environment& env) {
    const int nodes = env.fleet;
    const auto& bus = fleet_bus;
    const auto poll = fleet_poll;
    const auto period = fleet_period;
    fmt::print(
        "\n### 7c. A fleet: {} edge nodes on one broker\n\n{} ioportd (server CPU), each on its "
        "own simulated bus (in this process, client CPU) of {} modules ({}) at 115200 baud, each "
        "module read every {} ms (`poll:`), every input word changing every {} ms, so that every "
        "read is published; one mosquitto (client CPU, sys_interval 1) and one subscriber to "
        "spBv1.0/{}/# and the broker's $SYS counters. The ioportd are started all at once, a "
        "thread each, as boxes coming back after a power cut; the births are timed from the "
        "first start. Then a window of steady publication. CPU from schedstat, idle CPUs free "
        "to halt.\n",
        nodes, nodes, bus.size(), hub_argument(bus), poll.count(), period.count(), group);
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: 7c skipped.\n", broker.why());
        return {};
    }
    Tally tally;
    std::mutex sys_mutex;
    std::map<std::string, std::vector<std::pair<Clock::time_point, double>>> sys;
    Subscriber subscriber(
        broker.port(),
        {fmt::format("spBv1.0/{}/#", group), "$SYS/broker/messages/received",
         "$SYS/broker/messages/sent", "$SYS/broker/bytes/received", "$SYS/broker/bytes/sent"},
        [&](const Received& message) {
            if (message.topic.starts_with("$SYS/")) {
                const std::string text(message.payload.begin(), message.payload.end());
                const std::scoped_lock lock(sys_mutex);
                sys[std::string(message.topic)].emplace_back(message.at, std::atof(text.c_str()));
                return;
            }
            tally.add(message);
        });
    if (!subscriber.ready()) return {{"7c. fleet", "the subscriber did not start", "", false}};

    std::vector<std::unique_ptr<TempDir>> dirs;
    std::vector<std::unique_ptr<InProcessSim>> sims;
    for (int i = 0; i < nodes; ++i) {
        dirs.push_back(std::make_unique<TempDir>());
        sims.push_back(std::make_unique<InProcessSim>(*dirs.back() / "tty", bus, timed_line(115200),
                                                      env.placement.client_cpu));
        if (!sims.back()->ready()) return {{"7c. fleet", "a simulator did not start", "", false}};
        sims.back()->wander(bus, period);
    }
    // All at once, as a plant's boxes come back after a power cut: one thread a node, each
    // forking its ioportd and waiting for it to listen. Each thread lives as long as its ioportd
    // and stops it: a child is sent SIGTERM when the thread that forked it ends
    // (PR_SET_PDEATHSIG, harness.cpp).
    std::vector<std::unique_ptr<Gateway>> gateways(static_cast<std::size_t>(nodes));
    std::vector<Clock::time_point> launched(static_cast<std::size_t>(nodes));
    std::latch started(nodes);
    std::latch release(1);
    std::vector<std::jthread> starters;
    const auto first = Clock::now();
    for (std::size_t i = 0; i < gateways.size(); ++i)
        starters.emplace_back([&, i] {
            launched[i] = Clock::now();
            gateways[i] = std::make_unique<Gateway>(
                env, *dirs[i],
                gateway_yaml({{*dirs[i] / "tty", 115200, bus, poll}}, 32, false,
                             mqtt_yaml(broker.port(), node_id(static_cast<int>(i)))));
            started.count_down();
            release.wait();
            gateways[i].reset();
        });
    // On every way out of here: the threads stop their ioportd and end.
    struct Release {
        std::latch& release;
        std::vector<std::jthread>& threads;
        ~Release() {
            release.count_down();
            threads.clear();
        }
    } stop_all{release, starters};
    started.wait();
    const auto all_launched = Clock::now();
    for (std::size_t i = 0; i < gateways.size(); ++i)
        if (!gateways[i]->started())
            return {{"7c. fleet", fmt::format("ioportd {} did not start", i), "", false}};
    const auto modules = static_cast<int>(bus.size());
    const bool born = wait_for(
        [&] {
            for (int i = 0; i < nodes; ++i) {
                const auto node = tally.node(node_id(i));
                if (!node || !node->nbirth || node->dbirths < modules) return false;
            }
            return true;
        },
        60s);
    std::vector<double> to_nbirth, to_dbirths;
    Clock::time_point last_nbirth = first, last_dbirth = first;
    int nbirths = 0, dbirths = 0;
    for (int i = 0; i < nodes; ++i) {
        const auto node = tally.node(node_id(i));
        if (!node || !node->nbirth) continue;
        ++nbirths;
        dbirths += std::min(node->dbirths, modules);
        const auto at = launched[static_cast<std::size_t>(i)];
        to_nbirth.push_back(microseconds(*node->nbirth - at));
        last_nbirth = std::max(last_nbirth, *node->nbirth);
        if (node->dbirths >= modules) {
            to_dbirths.push_back(microseconds(node->last_dbirth - at));
            last_dbirth = std::max(last_dbirth, node->last_dbirth);
        }
    }
    const auto nb = summarize(to_nbirth);
    const auto db = summarize(to_dbirths);
    fmt::print(
        "\nStarting the {} ioportd (until each listened) took {:.2f} s. {} of {} NBIRTHs and {} of "
        "{} DBIRTHs arrived; "
        "the last NBIRTH {:.2f} s and the last DBIRTH {:.2f} s after the first start.\n",
        nodes, seconds(all_launched - first), nbirths, nodes, dbirths, nodes * modules,
        seconds(last_nbirth - first), seconds(last_dbirth - first));
    const Table births({"one node's start →", "p50 ms", "max ms", "nodes"});
    births.row({"its NBIRTH at the subscriber", fmt::format("{:.1f}", ms(nb.p50)),
                fmt::format("{:.1f}", ms(nb.max)), fmt::format("{}", nb.count)});
    births.row({"its last DBIRTH (every module polled)", fmt::format("{:.1f}", ms(db.p50)),
                fmt::format("{:.1f}", ms(db.max)), fmt::format("{}", db.count)});

    // Steady publication.
    std::this_thread::sleep_for(env.quick ? 200ms : 2s);
    const auto fleet_cpu = [&] { return cpu_time_of(gateways); };
    const auto window = env.window(10s);
    const auto counts_before = tally.counts();
    const auto nodes_before = fleet_cpu();
    const auto broker_before = cpu_time(broker.pid());
    const auto start = Clock::now();
    std::this_thread::sleep_for(window);
    const auto nodes_cpu = fleet_cpu() - nodes_before;
    const auto broker_cpu = cpu_time(broker.pid()) - broker_before;
    const auto end = Clock::now();
    const double s = seconds(end - start);
    const auto counts = tally.counts() - counts_before;
    const std::uint64_t lost_in_total = tally.counts().lost;
    // The broker's rate from its own counters: the samples within the window.
    const auto sys_rate = [&](const std::string& topic) -> std::optional<double> {
        const std::scoped_lock lock(sys_mutex);
        const auto found = sys.find(topic);
        if (found == sys.end()) return std::nullopt;
        std::optional<std::pair<Clock::time_point, double>> a, b;
        for (const auto& sample : found->second) {
            if (sample.first < start || sample.first > end + 500ms) continue;
            if (!a) a = sample;
            b = sample;
        }
        if (!a || !b || b->first <= a->first) return std::nullopt;
        return (b->second - a->second) / seconds(b->first - a->first);
    };
    const auto received = sys_rate("$SYS/broker/messages/received");
    const auto sent = sys_rate("$SYS/broker/messages/sent");
    const auto bytes_received = sys_rate("$SYS/broker/bytes/received");
    const auto bytes_sent = sys_rate("$SYS/broker/bytes/sent");
    const auto rate_text = [](std::optional<double> r, std::string_view unit) {
        return r ? fmt::format("{:.0f} {}", *r, unit) : std::string("(no $SYS samples)");
    };
    const double messages_per_s = static_cast<double>(counts.messages) / s;
    const double per_node = messages_per_s / nodes;
    const double broker_pct = core_percent(broker_cpu, s);
    const double nodes_pct = core_percent(nodes_cpu, s);
    const Table steady({"figure", "over the window", "per node"});
    steady.row(
        {"messages/s at the subscriber (DDATA)",
         fmt::format("{:.0f} ({:.0f})", messages_per_s, static_cast<double>(counts.ddata) / s),
         fmt::format("{:.1f}", per_node)});
    steady.row({"bytes/s at the subscriber (topics and payloads)",
                fmt::format("{:.1f} KiB/s", static_cast<double>(counts.bytes) / 1024 / s),
                fmt::format("{:.0f} B/s", static_cast<double>(counts.bytes) / s / nodes)});
    steady.row({"the broker's messages received / sent ($SYS)",
                fmt::format("{} / {}", rate_text(received, "/s"), rate_text(sent, "/s")), ""});
    steady.row(
        {"the broker's bytes received / sent ($SYS)",
         fmt::format("{} / {}", rate_text(bytes_received, "B/s"), rate_text(bytes_sent, "B/s")),
         ""});
    steady.row({"the broker's CPU", fmt::format("**{:.2f} %** of a core", broker_pct),
                fmt::format("{:.3f} %", broker_pct / nodes)});
    steady.row({"the ioportd's CPU, all together", fmt::format("{:.2f} % of a core", nodes_pct),
                fmt::format("{:.2f} %", nodes_pct / nodes)});
    steady.row({"messages lost (gaps in the nodes' seq), whole run",
                fmt::format("{}", lost_in_total), ""});
    fmt::print(
        "\nThis box and its broker held {} nodes × {:.1f} msg/s = {:.0f} msg/s ({:.1f} KiB/s) at "
        "{:.1f} % of one core for the broker; the {} ioportd together {:.1f} % ({:.2f} % each), "
        "{} lost.\n",
        nodes, per_node, messages_per_s, static_cast<double>(counts.bytes) / 1024 / s, broker_pct,
        nodes, nodes_pct, nodes_pct / nodes, lost_in_total);
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_fleet","nodes":{},"modules_per_node":{},"poll_ms":{},"launch_s":{:.3f},"all_nbirths":{},"all_dbirths":{},"last_nbirth_s":{:.3f},"last_dbirth_s":{:.3f},"nbirth_p50_ms":{:.1f},"nbirth_max_ms":{:.1f},"dbirths_p50_ms":{:.1f},"dbirths_max_ms":{:.1f},"messages_per_s":{:.1f},"ddata_per_s":{:.1f},"bytes_per_s":{:.0f},"broker_received_per_s":{},"broker_sent_per_s":{},"broker_cpu_pct":{:.3f},"nodes_cpu_pct":{:.3f},"lost":{}}})",
        nodes, bus.size(), poll.count(), seconds(all_launched - first), nbirths, dbirths,
        seconds(last_nbirth - first), seconds(last_dbirth - first), ms(nb.p50), ms(nb.max),
        ms(db.p50), ms(db.max), messages_per_s, static_cast<double>(counts.ddata) / s,
        static_cast<double>(counts.bytes) / s, received ? fmt::format("{:.1f}", *received) : "null",
        sent ? fmt::format("{:.1f}", *sent) : "null", broker_pct, nodes_pct, lost_in_total));
    return {{fmt::format("7c. {} edge nodes on one broker: births, loss", nodes),
             fmt::format("{}/{} NBIRTH, {}/{} DBIRTH in {:.2f} s; {:.0f} msg/s, broker {:.1f} %, "
                         "{} lost",
                         nbirths, nodes, dbirths, nodes * modules, seconds(last_dbirth - first),
                         messages_per_s, broker_pct, lost_in_total),
             "every birth, none lost", born && lost_in_total == 0}};
}

// --- d. A broker outage, with the store -------------------------------------------------------

// The number in a store's delivered mark: once everything is forwarded, how many records the
// store ever took (a fresh store numbers them from 1).
std::uint64_t delivered_mark(const std::filesystem::path& store) {
    std::uint64_t delivered = 0;
    std::ifstream mark(store / "delivered", std::ios::binary);
    std::array<char, 8> bytes{};
    if (mark.read(bytes.data(), bytes.size()))
        for (auto byte = bytes.rbegin(); byte != bytes.rend(); ++byte)
            delivered = delivered << 8 | static_cast<std::uint8_t>(*byte);
    return delivered;
}

// What a store directory holds now, read as ioportd would find it on opening (the files only
// read): records after the delivered mark, and the bytes of the segments.
struct OnDisk {
    std::uint64_t records = 0;
    std::uint64_t bytes = 0;
};
OnDisk on_disk(const std::filesystem::path& store) {
    OnDisk found;
    const auto delivered = delivered_mark(store);
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator(store, ec)) {
        if (entry.path().extension() != ".seg") continue;
        std::ifstream file(entry.path(), std::ios::binary);
        const std::vector<std::uint8_t> bytes{std::istreambuf_iterator<char>(file), {}};
        found.bytes += bytes.size();
        for (const auto& record : store::scan_segment(bytes).records)
            if (record.number > delivered) ++found.records;
    }
    return found;
}

// What a subscriber saw of one session of the node after the outage.
struct AfterOutage {
    std::mutex mutex;
    Tally tally;
    std::uint64_t historical = 0;
    std::optional<Clock::time_point> last_historical;
    std::optional<std::uint64_t> word_alias;
    std::map<std::uint64_t, Clock::time_point> arrived;  // dim16 0's word -> its live DDATA
};

// The number in the restarted ioportd's line "Sparkplug store …: N record(s) to forward".
std::optional<std::uint64_t> records_to_forward(const std::string& log) {
    const auto at = log.find(" record(s) to forward");
    if (at == std::string::npos) return std::nullopt;
    const auto from = log.rfind(' ', at - 1);
    return std::strtoull(log.c_str() + from + 1, nullptr, 10);
}

// With `crash`, 7e: ioportd is killed (SIGKILL) in the middle of the outage and started again.
std::vector<Verdict> outage(const Environment& env, bool crash) {
    const auto bus = full_bus();
    const auto analog = analog_of(bus);
    const auto period = 5ms;
    const auto away =
        env.quick ? 1s : std::chrono::duration_cast<std::chrono::seconds>(env.window(60s));
    const auto connected_window = std::min<std::chrono::seconds>(away, 60s);
    const int forward_rate = env.quick ? 2000 : 1000;
    const ModuleAddress target{ModuleType::dim16, 0};
    const auto target_id = sparkplug::device_id("hub0", target);
    const std::string name = crash ? "7e. outage, kill -9" : "7d. outage";
    if (crash)
        fmt::print(
            "\n### 7e. A broker outage of {} s, with ioportd killed in its middle\n\nAs 7d, but "
            "half-way through the outage ioportd is killed (SIGKILL) and started again at once, "
            "on the same store. \"Written before the kill\": the records in the store's files "
            "just before it (read from the files); \"found after\": the files read after it, and "
            "the count the restarted ioportd reports on opening the store. The changes of the "
            "seconds ioportd is down are not recorded: no process watches the bus then.\n",
            away.count());
    else
        fmt::print(
            "\n### 7d. A broker outage of {} s, with the store\n\nA full bus at 115200 baud "
            "(modelled, simulated in this process) with its {} analog modules' every channel "
            "moving "
            "every {} ms, so that every read of them is a new value; ioportd an edge node on a "
            "local "
            "mosquitto with `store:` (forward_rate {}). The broker is stopped for {} s and started "
            "again on the same port; a new subscriber is there before ioportd's next CONNECT. "
            "\"Recorded\": the records the store took, from its delivered mark once everything is "
            "forwarded; \"forwarded\": the historical DDATA that subscriber received. Bytes: what "
            "ioportd wrote during the outage (/proc/PID/io: to write(), and to the block device) "
            "and "
            "the store's files at its end, per record then on disk. CPU: ioportd's, connected "
            "(live "
            "DDATA) for up to 60 s before the outage, and during it (storing instead). Live "
            "latency: "
            "dim16 0's word set at the simulator 60–140 ms apart, to the live DDATA carrying it, "
            "while the backlog is forwarded and after.\n",
            away.count(), analog.size(), period.count(), forward_rate, away.count());
    TempDir dir, restarted_dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: benchmark 7d skipped.\n", broker.why());
        return {};
    }
    InProcessSim sim(dir / "tty", bus, timed_line(115200), env.placement.client_cpu);
    const auto store = dir.path() / "store";
    // Watching the births of the first session: subscribed before ioportd starts.
    Tally before;
    auto watching = std::make_unique<Subscriber>(
        broker.port(), std::vector<std::string>{fmt::format("spBv1.0/{}/#", group)},
        [&](const Received& message) { before.add(message); });
    const auto yaml = gateway_yaml({{dir / "tty", 115200, bus}}, 32, false,
                                   mqtt_yaml(broker.port(), node_id(0)) +
                                       fmt::format("  store:\n    path: {}\n    forward_rate: {}\n",
                                                   store.string(), forward_rate));
    auto gateway = std::make_unique<Gateway>(env, dir, yaml);
    if (!sim.ready() || !watching->ready() || !gateway->started() ||
        !gateway->wait_until_polling() ||
        !wait_for(
            [&] {
                const auto node = before.node(node_id(0));
                return node && node->dbirths >= static_cast<int>(bus.size());
            },
            10s))
        return {{name, "ioportd did not start", "", false}};
    watching.reset();
    sim.wander(analog, period);
    std::this_thread::sleep_for(env.quick ? 100ms : 1s);
    const auto cpu_connected_start = cpu_time(gateway->pid());
    std::this_thread::sleep_for(connected_window);
    const auto cpu_connected = cpu_time(gateway->pid()) - cpu_connected_start;

    const auto io_before = process_io(gateway->pid());
    const auto cpu_before = cpu_time(gateway->pid());
    broker.stop();
    struct {
        std::uint64_t written = 0, found = 0;
        std::optional<std::uint64_t> reported;
        double down_s = 0;
    } killed;
    if (crash) {
        const auto half = std::chrono::milliseconds(away) / 2;
        std::this_thread::sleep_for(half);
        killed.written = on_disk(store).records;
        ::kill(gateway->pid(), SIGKILL);
        const auto at = Clock::now();
        gateway.reset();
        killed.found = on_disk(store).records;
        gateway = std::make_unique<Gateway>(env, restarted_dir, yaml);
        if (!gateway->started() || !gateway->wait_until_polling())
            return {{name, "ioportd did not start again", "", false}};
        killed.down_s = seconds(Clock::now() - at);
        killed.reported = records_to_forward(gateway->log());
        std::this_thread::sleep_until(at + (std::chrono::milliseconds(away) - half));
    } else {
        std::this_thread::sleep_for(away);
    }
    const auto cpu_away = cpu_time(gateway->pid()) - cpu_before;
    const auto io_after = process_io(gateway->pid());
    const auto stored = on_disk(store);
    if (!broker.restart()) return {{name, "mosquitto did not restart", "", false}};

    AfterOutage after;
    Subscriber subscriber(
        broker.port(), {fmt::format("spBv1.0/{}/#", group)}, [&](const Received& message) {
            after.tally.add(message);
            const auto topic = sparkplug::parse_topic(message.topic);
            const auto payload = sparkplug::decode(message.payload);
            if (!topic || !payload || payload->metrics.empty()) return;
            const std::scoped_lock lock(after.mutex);
            if (payload->metrics.front().is_historical) {
                ++after.historical;
                after.last_historical = message.at;
                return;
            }
            if (topic->device != target_id) return;
            for (const auto& metric : payload->metrics) {
                if (topic->type == sparkplug::MessageType::dbirth && metric.name == "word")
                    after.word_alias = metric.alias;
                const auto* value =
                    metric.value ? std::get_if<std::uint64_t>(&*metric.value) : nullptr;
                if (topic->type == sparkplug::MessageType::ddata && after.word_alias &&
                    metric.alias == after.word_alias && value != nullptr)
                    after.arrived.try_emplace(*value, message.at);
            }
        });
    // ioportd comes back at its next reconnect (1 s doubling to 30 s since the loss).
    if (!subscriber.ready() ||
        !wait_for([&] { return after.tally.node(node_id(0)).has_value(); }, 40s))
        return {{name, "ioportd did not reconnect", "", false}};
    const auto births = after.tally.node(node_id(0))->nbirth;

    std::mt19937 random(26);
    std::uint16_t next_word = 0x2000;
    const int changes = env.quick ? 5 : 100;
    const auto probe = [&] {
        std::uniform_int_distribution<int> pause_us(60'000, 140'000);
        std::vector<std::pair<std::uint16_t, Clock::time_point>> applied;
        for (int i = 0; i < changes; ++i) {
            std::this_thread::sleep_for(std::chrono::microseconds(pause_us(random)));
            const auto word = next_word++;
            applied.emplace_back(word, sim.set_values(target, {word}));
        }
        wait_for(
            [&] {
                const std::scoped_lock lock(after.mutex);
                return after.arrived.contains(applied.back().first);
            },
            2s);
        std::vector<double> latencies;
        const std::scoped_lock lock(after.mutex);
        for (const auto& [word, at] : applied)
            if (const auto found = after.arrived.find(word); found != after.arrived.end())
                latencies.push_back(microseconds(found->second - at));
        return summarize(latencies);
    };
    const auto forwarding_latency = probe();
    bool forwarding_throughout = false;
    {
        const std::scoped_lock lock(after.mutex);
        forwarding_throughout = after.historical < stored.records;
    }
    // Drained: the store's files hold nothing undelivered, and its mark is written (at a sync).
    const bool drained = wait_for(
        [&] { return on_disk(store).records == 0 && delivered_mark(store) > 0; },
        std::chrono::seconds(10 + 2 * stored.records / static_cast<std::uint64_t>(forward_rate)));
    std::this_thread::sleep_for(1100ms);  // the sync that writes the last mark
    const auto idle_latency = probe();

    const auto recorded = delivered_mark(store);
    std::uint64_t received = 0;
    double forward_s = 0;
    {
        const std::scoped_lock lock(after.mutex);
        received = after.historical;
        if (births && after.last_historical) forward_s = seconds(*after.last_historical - *births);
    }
    const auto counts = after.tally.counts();
    const double n = static_cast<double>(std::max<std::uint64_t>(stored.records, 1));
    const double written = static_cast<double>(io_after.wchar - io_before.wchar) / n;
    const double to_disk = static_cast<double>(io_after.write_bytes - io_before.write_bytes) / n;
    const double away_s = static_cast<double>(away.count());
    const double connected_pct =
        core_percent(cpu_connected, static_cast<double>(connected_window.count()));
    const double away_pct = core_percent(cpu_away, away_s);
    Table table({"", "value"});
    if (crash) {
        table.row({"records in the store's files just before the kill / just after it",
                   fmt::format("{} / {}", killed.written, killed.found)});
        table.row({"records the restarted ioportd found on opening the store",
                   killed.reported ? fmt::format("{}", *killed.reported) : "(no log line)"});
        table.row({"kill to polling again (changes in this time are not recorded)",
                   fmt::format("{:.2f} s", killed.down_s)});
    }
    table.row({"records the store took (its mark, all forwarded)", fmt::format("{}", recorded)});
    table.row({"historical DDATA received", fmt::format("{}", received)});
    table.row({"forwarding: from NBIRTH to the last historical DDATA",
               fmt::format("{:.1f} s ({:.0f} a second)", forward_s,
                           forward_s > 0 ? static_cast<double>(received) / forward_s : 0.0)});
    table.row({"in the store at the end of the outage",
               fmt::format("{} records, {:.1f} KiB, {:.0f} B a record", stored.records,
                           static_cast<double>(stored.bytes) / 1024,
                           static_cast<double>(stored.bytes) / n)});
    if (!crash) {  // one process's figures: across the kill they would mix two
        table.row({"written by ioportd during the outage, a record: to write() / to the disk",
                   fmt::format("{:.0f} B / {:.0f} B", written, to_disk)});
        table.row({"ioportd CPU: connected (live DDATA) / during the outage (storing)",
                   fmt::format("{:.2f} % / {:.2f} %", connected_pct, away_pct)});
    }
    table.row({"seq gaps at the subscriber after the outage", fmt::format("{}", counts.lost)});
    const auto latency_text = [&](const Summary& l) {
        return fmt::format("p50 {:.2f} ms, p99 {:.2f} ms, max {:.2f} ms ({} of {})", ms(l.p50),
                           ms(l.p99), ms(l.max), l.count, changes);
    };
    table.row({fmt::format("live change → DDATA while forwarding{}",
                           forwarding_throughout ? "" : " (the backlog ran out first)"),
               latency_text(forwarding_latency)});
    table.row({"live change → DDATA, no backlog", latency_text(idle_latency)});
    if (crash) {
        machine_line(fmt::format(
            R"({{"bench":"sparkplug_outage_kill","outage_s":{},"written_before_kill":{},"found_after_kill":{},"reported_at_restart":{},"down_s":{:.3f},"recorded":{},"forwarded":{},"forward_s":{:.2f},"seq_gaps":{}}})",
            away.count(), killed.written, killed.found,
            killed.reported ? fmt::format("{}", *killed.reported) : "null", killed.down_s, recorded,
            received, forward_s, counts.lost));
        const bool kept = killed.found >= killed.written && killed.reported == killed.found;
        return {{fmt::format("7e. kill -9 in a {} s outage: nothing written lost", away.count()),
                 fmt::format("{} written before the kill, {} found after; {} recorded, {} "
                             "forwarded",
                             killed.written, killed.found, recorded, received),
                 "every record written before the kill forwarded",
                 kept && drained && recorded > 0 && received == recorded && counts.lost == 0}};
    }
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_outage","outage_s":{},"recorded":{},"forwarded":{},"forward_s":{:.2f},"stored_at_end":{},"store_bytes":{},"wchar_per_record":{:.1f},"disk_per_record":{:.1f},"cpu_connected_pct":{:.3f},"cpu_outage_pct":{:.3f},"seq_gaps":{},"live_p99_forwarding_ms":{:.3f},"live_p99_idle_ms":{:.3f}}})",
        away.count(), recorded, received, forward_s, stored.records, stored.bytes, written, to_disk,
        connected_pct, away_pct, counts.lost, ms(forwarding_latency.p99), ms(idle_latency.p99)));
    return {{fmt::format("7d. a {} s broker outage: recorded = forwarded", away.count()),
             fmt::format("{} recorded, {} forwarded in {:.1f} s; {:.0f} B written a record",
                         recorded, received, forward_s, written),
             "every recorded change forwarded, none lost",
             drained && recorded > 0 && received == recorded && counts.lost == 0}};
}

// --- f. A fleet forwarding its backlogs at once ---------------------------------------------

// "Sparkplug: forwarded N stored record(s) in S s": the records of each such line, summed, and
// whether there was one.
std::optional<std::uint64_t> forwarded_in_log(const std::string& log) {
    std::optional<std::uint64_t> total;
    for (auto at = log.find("Sparkplug: forwarded "); at != std::string::npos;
         at = log.find("Sparkplug: forwarded ", at + 1))
        total = total.value_or(0) +
                std::strtoull(log.c_str() + at + std::string_view("Sparkplug: forwarded ").size(),
                              nullptr, 10);
    return total;
}

std::vector<Verdict> backlog(const Environment& env) {
    const int nodes = env.fleet;
    const auto& bus = fleet_bus;
    const auto poll = fleet_poll;
    const auto period = fleet_period;
    const auto away = std::chrono::duration_cast<std::chrono::seconds>(env.window(60s));
    fmt::print(
        "\n### 7f. {} edge nodes forwarding a {} s backlog to one broker at once\n\nThe fleet of "
        "7c ({} ioportd, each on its own simulated bus of {} modules read every {} ms, every "
        "input changing every {} ms), each with `store:` at the default forward_rate (200 a "
        "second). The broker is stopped for {} s; then every ioportd is paused (SIGSTOP), the "
        "broker started again on the same port and a subscriber connected, and the ioportd "
        "resumed (SIGCONT), so that the subscriber sees every session from its NBIRTH. Drained: "
        "each ioportd logged the end of its forwarding. Recorded: what the stores' delivered "
        "marks grew by from before the outage; forwarded: the historical DDATA the subscriber "
        "received. CPU from the broker's "
        "resumption to the last node drained.\n",
        nodes, away.count(), nodes, bus.size(), poll.count(), period.count(), away.count());
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: 7f skipped.\n", broker.why());
        return {};
    }
    std::vector<std::unique_ptr<TempDir>> dirs;
    std::vector<std::unique_ptr<InProcessSim>> sims;
    for (int i = 0; i < nodes; ++i) {
        dirs.push_back(std::make_unique<TempDir>());
        sims.push_back(std::make_unique<InProcessSim>(*dirs.back() / "tty", bus, timed_line(115200),
                                                      env.placement.client_cpu));
        if (!sims.back()->ready()) return {{"7f. backlog", "a simulator did not start", "", false}};
    }
    std::vector<std::unique_ptr<Gateway>> gateways;
    for (int i = 0; i < nodes; ++i) {
        const auto& d = *dirs[static_cast<std::size_t>(i)];
        gateways.push_back(std::make_unique<Gateway>(
            env, d,
            gateway_yaml({{d / "tty", 115200, bus, poll}}, 32, false,
                         mqtt_yaml(broker.port(), node_id(i)) +
                             fmt::format("  store:\n    path: {}\n", d / "store"))));
        if (!gateways.back()->started())
            return {{"7f. backlog", fmt::format("ioportd {} did not start", i), "", false}};
    }
    for (auto& sim : sims)
        sim->wander(bus, period);
    std::this_thread::sleep_for(2s);
    // What a node polled before its first CONNECT was stored and forwarded already, before the
    // subscriber was there: counted from here (the marks are synced within a second).
    std::vector<std::uint64_t> before_outage;
    for (const auto& d : dirs)
        before_outage.push_back(delivered_mark(*d / "store"));
    broker.stop();
    std::this_thread::sleep_for(away);
    for (const auto& gateway : gateways)
        ::kill(gateway->pid(), SIGSTOP);
    const bool restarted = broker.restart();
    struct {
        std::mutex mutex;
        std::map<std::string, std::uint64_t> historical;
    } seen;
    Tally tally;
    Subscriber subscriber(broker.port(), {fmt::format("spBv1.0/{}/#", group)},
                          [&](const Received& message) {
                              tally.add(message);
                              const auto topic = sparkplug::parse_topic(message.topic);
                              const auto payload = sparkplug::decode(message.payload);
                              if (!topic || !payload || payload->metrics.empty() ||
                                  !payload->metrics.front().is_historical)
                                  return;
                              const std::scoped_lock lock(seen.mutex);
                              ++seen.historical[topic->node];
                          });
    const auto fleet_cpu = [&] { return cpu_time_of(gateways); };
    const auto nodes_before = fleet_cpu();
    const auto broker_before = cpu_time(broker.pid());
    const auto resumed = Clock::now();
    for (const auto& gateway : gateways)
        ::kill(gateway->pid(), SIGCONT);
    if (!restarted || !subscriber.ready())
        return {{"7f. backlog", "the broker or the subscriber did not start again", "", false}};
    // Each node reconnects at its next attempt (1 s doubling to 30 s since the loss), then
    // forwards at 200 a second.
    std::vector<std::optional<std::uint64_t>> forwarded(static_cast<std::size_t>(nodes));
    Clock::time_point last_drained = resumed;
    // CPU up to the last node drained, not to the end of the wait.
    auto nodes_cpu = std::chrono::nanoseconds{}, broker_cpu = std::chrono::nanoseconds{};
    const bool drained = wait_for(
        [&] {
            bool all = true;
            for (std::size_t i = 0; i < gateways.size(); ++i) {
                if (forwarded[i]) continue;
                forwarded[i] = forwarded_in_log(gateways[i]->log());
                if (forwarded[i]) {
                    last_drained = Clock::now();
                    nodes_cpu = fleet_cpu() - nodes_before;
                    broker_cpu = cpu_time(broker.pid()) - broker_before;
                }
                all = all && forwarded[i].has_value();
            }
            if (!all) std::this_thread::sleep_for(250ms);
            return all;
        },
        std::chrono::seconds(60 + 2 * away.count()));
    const double drain_s = seconds(last_drained - resumed);
    std::this_thread::sleep_for(1100ms);  // the syncs that write the last marks
    std::uint64_t recorded = 0, received = 0, short_nodes = 0, doubled = 0;
    {
        const std::scoped_lock lock(seen.mutex);
        for (int i = 0; i < nodes; ++i) {
            const auto mark = delivered_mark(*dirs[static_cast<std::size_t>(i)] / "store") -
                              before_outage[static_cast<std::size_t>(i)];
            const auto got = seen.historical[node_id(i)];
            recorded += mark;
            received += got;
            short_nodes += got < mark;
            doubled += got > mark ? got - mark : 0;
            if (got != mark || !forwarded[static_cast<std::size_t>(i)]) {
                const auto log = gateways[static_cast<std::size_t>(i)]->log();
                fmt::print("\n{}: {} recorded, {} received{}; its log ends:\n{}\n", node_id(i),
                           mark, got,
                           forwarded[static_cast<std::size_t>(i)] ? "" : ", never drained",
                           log.substr(log.size() > 1500 ? log.size() - 1500 : 0));
            }
        }
    }
    const auto counts = tally.counts();
    const double broker_pct = core_percent(broker_cpu, std::max(drain_s, 1e-3));
    const double nodes_pct = core_percent(nodes_cpu, std::max(drain_s, 1e-3));
    Table table({"", "value"});
    table.row({"records the stores took (their delivered marks once drained)",
               fmt::format("{} ({} a node)", recorded, recorded / static_cast<unsigned>(nodes))});
    table.row({"historical DDATA the subscriber received",
               fmt::format("{} ({} twice; {} node(s) short)", received, doubled, short_nodes)});
    table.row({"resumption to the last node drained",
               fmt::format("{:.1f} s ({:.0f} historical DDATA a second, all nodes)", drain_s,
                           static_cast<double>(received) / std::max(drain_s, 1e-3))});
    table.row({"the broker's CPU, over that time", fmt::format("{:.1f} % of a core", broker_pct)});
    table.row({"the ioportd's CPU, all together, over that time",
               fmt::format("{:.1f} % of a core ({:.2f} % each)", nodes_pct, nodes_pct / nodes)});
    table.row({"seq gaps at the subscriber", fmt::format("{}", counts.lost)});
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_backlog","nodes":{},"outage_s":{},"recorded":{},"forwarded":{},"doubled":{},"short_nodes":{},"drain_s":{:.2f},"broker_cpu_pct":{:.3f},"nodes_cpu_pct":{:.3f},"seq_gaps":{}}})",
        nodes, away.count(), recorded, received, doubled, short_nodes, drain_s, broker_pct,
        nodes_pct, counts.lost));
    return {{fmt::format("7f. {} nodes forward a {} s backlog at once", nodes, away.count()),
             fmt::format("{} recorded, {} forwarded in {:.1f} s; broker {:.1f} %", recorded,
                         received, drain_s, broker_pct),
             "every recorded change forwarded, none lost",
             drained && recorded > 0 && short_nodes == 0 && counts.lost == 0}};
}

// --- g. A full store at start-up and at a reload ------------------------------------------------

// Fills a store to `size` with stored DDATA of one acm3p channel, as the node keeps them, until
// its oldest records start to go: a store as full as max_size lets it be. The records it holds.
std::uint64_t fill_store(const std::filesystem::path& dir, std::uint64_t size) {
    auto files = daemon::StoreFiles::open(dir, size);
    if (!files) return 0;
    for (std::uint64_t n = 0; files->counts().dropped == 0; ++n) {
        const std::uint64_t now = 1796183655123 + n * 50;
        const auto raw = static_cast<std::uint64_t>(n * 37 % 65536);
        const auto body = sparkplug::encode_stored(
            {"hub0.acm3p.0",
             sparkplug::Payload{now,
                                std::nullopt,
                                {sparkplug::Metric{"raw/0", std::nullopt, now, 6, raw},
                                 sparkplug::Metric{"value/0", std::nullopt, now, 9,
                                                   static_cast<float>(raw) / 655.35F}}}});
        if (!files->append(body)) return 0;
    }
    (void)files->sync();
    return files->counts().records;
}

// Modbus answers on one connection, back to back, while it runs: when each was asked, and how
// long it took.
class ModbusProbe {
  public:
    explicit ModbusProbe(std::uint16_t port, std::optional<int> cpu)
        : thread_([this, port, cpu] {
              pin_this_thread(cpu);
              ModbusConnection connection(port);
              while (!stop_) {
                  const auto asked = Clock::now();
                  const bool ok = connection.input_registers(0, 1).has_value();
                  const auto took = Clock::now() - asked;
                  const std::scoped_lock lock(mutex_);
                  answers_.push_back({asked, took, ok});
                  std::this_thread::sleep_for(5ms);
              }
          }) {}
    ~ModbusProbe() {
        stop_ = true;
        thread_.join();
    }
    // The latencies of the requests asked in [from, until), in µs, and how many failed.
    std::pair<Summary, std::size_t> between(Clock::time_point from, Clock::time_point until) {
        std::vector<double> latencies;
        std::size_t failed = 0;
        const std::scoped_lock lock(mutex_);
        for (const auto& answer : answers_)
            if (answer.asked >= from && answer.asked < until) {
                latencies.push_back(microseconds(answer.took));
                failed += answer.ok ? 0 : 1;
            }
        return {summarize(std::move(latencies)), failed};
    }

  private:
    struct Answer {
        Clock::time_point asked;
        Clock::duration took;
        bool ok = false;
    };
    std::mutex mutex_;
    std::vector<Answer> answers_;
    std::atomic<bool> stop_{false};
    std::thread thread_;
};

std::vector<Verdict> full_store(const Environment& env) {
    const std::uint64_t size = env.quick ? std::uint64_t{4} << 20 : config::max_store_size;
    fmt::print(
        "\n### 7g. A store full at the largest max_size, at start-up and at a reload\n\nA store "
        "filled to max_size = {} MiB (the largest the configuration allows) with stored DDATA of "
        "an acm3p channel, ioportd an edge node on it and on a full bus at 115200 baud. "
        "Start-up: from the process's start to its \"started\" line (READY=1 follows it at "
        "once) and to the store's line (its scan done, on the disk thread). Reload: a SIGHUP "
        "that changes mqtt (a new node opens the same store and scans it again) while a Modbus "
        "client reads every 5 ms; its latency from the SIGHUP to the scan's end, against the "
        "3 s before.\n",
        size >> 20);
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: benchmark 7g skipped.\n", broker.why());
        return {};
    }
    const auto bus = full_bus();
    InProcessSim sim(dir / "tty", bus, timed_line(115200), env.placement.client_cpu);
    const auto store = dir.path() / "store";
    const auto filling = Clock::now();
    const auto records = fill_store(store, size);
    const auto fill_s = seconds(Clock::now() - filling);
    const auto yaml = [&](std::string_view more) {
        return gateway_yaml({{dir / "tty", 115200, bus}}, 32, false,
                            mqtt_yaml(broker.port(), node_id(0)) +
                                fmt::format("  store:\n    path: {}\n    max_size: {}MiB\n{}",
                                            store.string(), size >> 20, more));
    };
    const std::string name = "7g. a full store";
    const auto found = [](const std::string& log, std::string_view what) {
        return log.find(what) != std::string::npos;
    };
    const auto launched = Clock::now();
    Gateway gateway(env, dir, yaml(""));
    std::optional<Clock::time_point> started, scanned;
    wait_for(
        [&] {
            const auto log = gateway.log();
            if (!started && found(log, " started: ")) started = Clock::now();
            if (!scanned && found(log, " record(s) to forward")) scanned = Clock::now();
            return started && scanned;
        },
        120s);
    if (!gateway.started() || !started || !scanned || !sim.ready() || !gateway.wait_until_polling())
        return {{name, "ioportd did not start", "", false}};
    ModbusConnection diagnostics(gateway.port());
    const auto cycle_ms =
        read_diagnostics(diagnostics).value_or(Diagnostics{}).last_cycle_100us / 10.0;

    ModbusProbe probe(gateway.port(), env.placement.client_cpu);
    std::this_thread::sleep_for(env.quick ? 300ms : 3s);
    std::ofstream(dir / "ioportd.yaml") << yaml("  deadband: 0.5\n");
    const auto hup = Clock::now();
    ::kill(gateway.pid(), SIGHUP);
    const auto scans = [&] {
        const auto log = gateway.log();
        std::size_t n = 0;
        for (auto at = log.find(" record(s) to forward"); at != std::string::npos;
             at = log.find(" record(s) to forward", at + 1))
            ++n;
        return n;
    };
    const bool rescanned = wait_for([&] { return scans() >= 2; }, 120s);
    const auto end = Clock::now();
    const auto [quiet, quiet_failed] = probe.between(hup - (env.quick ? 300ms : 3s), hup);
    const auto [reload, reload_failed] = probe.between(hup, end);
    const auto startup_s = seconds(*started - launched);
    const auto scan_s = seconds(*scanned - launched);
    const auto rescan_s = seconds(end - hup);

    Table table({"", "value"});
    table.row({"the store",
               fmt::format("{} MiB, {} records, filled in {:.1f} s", size >> 20, records, fill_s)});
    table.row({"start-up: to \"started\" (READY=1) / to the scan's end",
               fmt::format("{:.2f} s / {:.2f} s", startup_s, scan_s)});
    table.row({"reload: SIGHUP to the new scan's end", fmt::format("{:.2f} s", rescan_s)});
    const auto latency_text = [](const Summary& l, std::size_t failed) {
        return fmt::format("p50 {:.2f} ms, p99 {:.2f} ms, max {:.2f} ms ({} requests, {} failed)",
                           ms(l.p50), ms(l.p99), ms(l.max), l.count, failed);
    };
    table.row({"Modbus, the 3 s before the reload", latency_text(quiet, quiet_failed)});
    table.row({"Modbus, from the SIGHUP to the scan's end", latency_text(reload, reload_failed)});
    table.row({"the bus's poll cycle", fmt::format("{:.1f} ms", cycle_ms)});
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_full_store","mib":{},"records":{},"startup_s":{:.3f},"scan_s":{:.3f},"rescan_s":{:.3f},"quiet_p99_ms":{:.3f},"reload_p99_ms":{:.3f},"reload_max_ms":{:.3f},"cycle_ms":{:.1f}}})",
        size >> 20, records, startup_s, scan_s, rescan_s, ms(quiet.p99), ms(reload.p99),
        ms(reload.max), cycle_ms));
    return {{fmt::format("{}: start-up to READY=1", name), fmt::format("{:.2f} s", startup_s),
             "well inside WatchdogSec=20s and the start timeout", startup_s < 5},
            {fmt::format("{}: Modbus p99 while a reload scans it", name),
             fmt::format("{:.2f} ms ({:.2f} ms before)", ms(reload.p99), ms(quiet.p99)),
             "within a poll cycle",
             rescanned && reload_failed == 0 && ms(reload.p99) <= std::max(cycle_ms, 1.0)}};
}

}  // namespace

std::vector<Verdict> sparkplug_outage(const Environment& env) {
    fmt::print("\n## 7d. Sparkplug store-and-forward\n\nWhat nothing lost costs (issue 26).\n");
    return outage(env, false);
}

std::vector<Verdict> sparkplug_outage_kill(const Environment& env) {
    return outage(env, true);
}

std::vector<Verdict> sparkplug_cost(const Environment& env) {
    fmt::print(
        "\n## 7. Sparkplug B edge node\n\nWhat the edge node (issue 17) costs: the latency of "
        "report by exception, ioportd's CPU to publish a bus that never holds still and what "
        "that does to Modbus, and (7c, not with --quick) a fleet of edge nodes on one broker.\n");
    auto verdicts = latency(env);
    if (verdicts.empty()) return verdicts;  // no broker
    const auto more = publication_cost(env);
    verdicts.insert(verdicts.end(), more.begin(), more.end());
    return verdicts;
}

std::vector<Verdict> sparkplug_full_store(const Environment& env) {
    return full_store(env);
}

std::vector<Verdict> sparkplug_backlog(const Environment& env) {
    if (env.quick || env.fleet <= 0) return {};
    return backlog(env);
}

std::vector<Verdict> sparkplug_fleet(const Environment& env) {
    if (env.quick || env.fleet <= 0) return {};
    return fleet(env);
}

}  // namespace ioport::bench
