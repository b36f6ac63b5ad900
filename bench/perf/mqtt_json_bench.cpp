// Benchmark 9, what plain MQTT with Home Assistant discovery costs (issue 28, gateway.md §6.3),
// beside the Sparkplug B edge node it runs with: the demo's bus (one module of each type but
// acm3c) at 115200 baud, every analog channel moving all the time. Two ioportd side by side on
// the same changing input and one local mosquitto: "Sparkplug" an edge node alone, "Sparkplug +
// JSON" the same edge node and an `mqtt_json:` output. Their CPU over the same windows, the
// messages each output delivers to a subscriber in this process, and Modbus at 64 connections on
// the one against the other.
#include <algorithm>
#include <atomic>
#include <thread>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"
#include "bench/perf/load.hpp"
#include "bench/perf/mqtt_broker.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::bench {
namespace {

constexpr std::string_view json_prefix = "bench/json";

// The demo's hub (config/ioportd-sim.yaml), named as §6.1 lets a plant name it.
std::vector<ModuleAddress> demo_bus() {
    return {{ModuleType::dim16, 0}, {ModuleType::dom16, 0}, {ModuleType::acm3p, 0},
            {ModuleType::lim16, 0}, {ModuleType::rgbdm, 0}, {ModuleType::mux8m, 0},
            {ModuleType::dccim, 0}, {ModuleType::dcvim, 0}};
}

std::string sparkplug_yaml(std::uint16_t port, std::string_view node) {
    return fmt::format(
        "mqtt:\n  broker: \"mqtt://127.0.0.1:{}\"\n  group_id: bench\n  edge_node_id: {}\n", port,
        node);
}

std::string json_yaml(std::uint16_t port) {
    return fmt::format("mqtt_json:\n  broker: \"mqtt://127.0.0.1:{}\"\n  topic_prefix: {}\n", port,
                       json_prefix);
}

// Messages a subscriber received, counted by output: DDATA of each edge node, and the JSON
// output's state documents and every message of it (discovery and availability included).
struct OutputCounts {
    std::uint64_t ddata_alone = 0, ddata_beside = 0, json_states = 0, json = 0, json_bytes = 0;
    OutputCounts operator-(const OutputCounts& o) const {
        return {ddata_alone - o.ddata_alone, ddata_beside - o.ddata_beside,
                json_states - o.json_states, json - o.json, json_bytes - o.json_bytes};
    }
    OutputCounts& operator+=(const OutputCounts& o) {
        ddata_alone += o.ddata_alone;
        ddata_beside += o.ddata_beside;
        json_states += o.json_states;
        json += o.json;
        json_bytes += o.json_bytes;
        return *this;
    }
};

class OutputTally {
  public:
    void add(const Received& message) {
        if (message.topic.starts_with(json_prefix)) {
            ++json_;
            json_bytes_ += message.topic.size() + message.payload.size();
            if (message.topic.ends_with("/state")) ++json_states_;
            return;
        }
        const auto topic = sparkplug::parse_topic(message.topic);
        if (!topic || topic->type != sparkplug::MessageType::ddata) return;
        ++(topic->node == "alone" ? ddata_alone_ : ddata_beside_);
    }
    OutputCounts counts() const {
        return {ddata_alone_.load(), ddata_beside_.load(), json_states_.load(), json_.load(),
                json_bytes_.load()};
    }

  private:
    std::atomic<std::uint64_t> ddata_alone_{0}, ddata_beside_{0}, json_states_{0}, json_{0},
        json_bytes_{0};
};

}  // namespace

std::vector<Verdict> mqtt_json_cost(const Environment& env) {
    const auto bus = demo_bus();
    const auto analog = analog_of(bus);
    const auto period = 5ms;
    fmt::print(
        "\n## 9. Plain MQTT and Home Assistant discovery beside Sparkplug B\n\nThe demo's bus ({} "
        "modules, names, units and scales on every one) at 115200 baud (modelled, simulated in "
        "this process), its {} analog modules' every channel moving every {} ms. Two ioportd on "
        "the server CPU on the same changing input, both edge nodes on one local mosquitto "
        "(client CPU): \"Sparkplug\" alone, \"Sparkplug + JSON\" with an `mqtt_json:` output "
        "too (discovery on, deadband 0, as the Sparkplug node's). Both run throughout: their CPU "
        "is measured over the same windows, and the Modbus load of benchmark 4 (64 connections, "
        "reads) goes to one and then the other in alternating rounds.\n",
        bus.size(), analog.size(), period.count());
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: benchmark 9 skipped.\n", broker.why());
        return {};
    }
    OutputTally tally;
    Subscriber subscriber(broker.port(), {"spBv1.0/bench/#", fmt::format("{}/#", json_prefix)},
                          [&](const Received& message) { tally.add(message); });
    TempDir dir_alone, dir_beside;
    InProcessSim sim_alone(dir_alone / "tty", bus, timed_line(115200), env.placement.client_cpu);
    InProcessSim sim_beside(dir_beside / "tty", bus, timed_line(115200), env.placement.client_cpu);
    const auto link = [&](const TempDir& d) { return LinkSpec{d / "tty", 115200, bus, {}, true}; };
    Gateway alone(
        env, dir_alone,
        gateway_yaml({link(dir_alone)}, 300, false, sparkplug_yaml(broker.port(), "alone")));
    Gateway beside(
        env, dir_beside,
        gateway_yaml({link(dir_beside)}, 300, false,
                     sparkplug_yaml(broker.port(), "beside") + json_yaml(broker.port())));
    if (!sim_alone.ready() || !sim_beside.ready() || !subscriber.ready() || !alone.started() ||
        !beside.started() || !alone.wait_until_polling() || !beside.wait_until_polling() ||
        !wait_for([&] { return tally.counts().json_states >= bus.size(); }, 10s))
        return {{"9. Plain MQTT", "ioportd did not start", "", false}};
    sim_alone.wander(analog, period);
    sim_beside.wander(analog, period);
    std::this_thread::sleep_for(env.quick ? 100ms : 1s);

    // 9a. CPU of both over the same windows, and the messages each output delivered.
    const int windows = env.quick ? 1 : 5;
    const auto window = env.window(3s);
    fmt::print("\n### 9a. CPU and messages ({} windows of {} ms)\n", windows, window.count());
    const Table cpu_table({"window", "Sparkplug, CPU", "Sparkplug + JSON, CPU", "ratio",
                           "DDATA/s alone", "DDATA/s beside", "JSON states/s", "JSON KiB/s"});
    std::vector<double> ratios;
    OutputCounts total, counts_before;
    const auto cpu = cpu_windows(
        {alone.pid(), beside.pid()}, windows, window, [&](int) { counts_before = tally.counts(); },
        [&](int i, const std::vector<std::chrono::nanoseconds>& used, double s) {
            const auto counts = tally.counts() - counts_before;
            const double alone_pct = core_percent(used[0], s);
            const double beside_pct = core_percent(used[1], s);
            ratios.push_back(beside_pct / alone_pct);
            cpu_table.row(
                {fmt::format("{}", i + 1), fmt::format("{:.2f} %", alone_pct),
                 fmt::format("{:.2f} %", beside_pct), fmt::format("{:.2f}", ratios.back()),
                 fmt::format("{:.0f}", static_cast<double>(counts.ddata_alone) / s),
                 fmt::format("{:.0f}", static_cast<double>(counts.ddata_beside) / s),
                 fmt::format("{:.0f}", static_cast<double>(counts.json_states) / s),
                 fmt::format("{:.1f}", static_cast<double>(counts.json_bytes) / 1024 / s)});
            total += counts;
        });
    const double total_seconds = cpu.seconds;
    const double alone_pct = cpu.percent(0);
    const double beside_pct = cpu.percent(1);
    const double states_per_s = static_cast<double>(total.json_states) / total_seconds;
    const double us_per_state = microseconds(cpu.total[1] - cpu.total[0]) /
                                static_cast<double>(std::max<std::uint64_t>(total.json_states, 1));
    const double cpu_ratio = median(ratios);
    fmt::print(
        "\nAll windows ({:.1f} s): ioportd {:.2f} % of a core with Sparkplug alone, {:.2f} % with "
        "JSON beside it: {:.3f}× (median of the windows {:.3f}×); {:.0f} JSON states/s ({:.0f} B "
        "each with its topic), {:.1f} µs of CPU per state document; DDATA/s {:.0f} alone, {:.0f} "
        "beside.\n",
        total_seconds, alone_pct, beside_pct, beside_pct / alone_pct, cpu_ratio, states_per_s,
        static_cast<double>(total.json_bytes) /
            static_cast<double>(std::max<std::uint64_t>(total.json, 1)),
        us_per_state, static_cast<double>(total.ddata_alone) / total_seconds,
        static_cast<double>(total.ddata_beside) / total_seconds);
    machine_line(fmt::format(
        R"({{"bench":"mqtt_json_cpu","modules":{},"analog_modules":{},"change_period_ms":{},"seconds":{:.2f},"cpu_alone_pct":{:.3f},"cpu_beside_pct":{:.3f},"ratio_total":{:.4f},"ratio_median":{:.4f},"json_states_per_s":{:.1f},"json_bytes_per_s":{:.0f},"us_per_state":{:.2f},"ddata_per_s_alone":{:.1f},"ddata_per_s_beside":{:.1f}}})",
        bus.size(), analog.size(), period.count(), total_seconds, alone_pct, beside_pct,
        beside_pct / alone_pct, cpu_ratio, states_per_s,
        static_cast<double>(total.json_bytes) / total_seconds, us_per_state,
        static_cast<double>(total.ddata_alone) / total_seconds,
        static_cast<double>(total.ddata_beside) / total_seconds));

    // 9b. Modbus at 64 connections, on the one and then the other.
    constexpr int connections = 64;
    const int rounds = env.quick ? 1 : 7;
    const auto load_window = env.window(3s);
    fmt::print(
        "\n### 9b. Modbus at {} connections, Sparkplug + JSON against Sparkplug alone ({} pairs "
        "of {} ms rounds, alternating)\n",
        connections, rounds, load_window.count());
    const Table rounds_table(
        {"round", "ioportd", "req/s", "p99 µs", "server CPU µs/req", "errors", "JSON states/s"});
    const auto rounds_run = alternating_rounds(
        {&alone, &beside}, connections, rounds, env.quick ? 100ms : 500ms, load_window,
        {.before = [&](int) { counts_before = tally.counts(); },
         .after =
             [&](int round, int json, const LoadResult& result, const Summary& latency,
                 double round_seconds) {
                 const auto counts = tally.counts() - counts_before;
                 rounds_table.row(
                     {fmt::format("{}", round + 1), json ? "Sparkplug + JSON" : "Sparkplug",
                      fmt::format("{:.0f}", result.per_second()),
                      fmt::format("{:.0f}", latency.p99),
                      fmt::format("{:.2f}", result.cpu_us_per_request()),
                      fmt::format("{}", result.errors),
                      json ? fmt::format("{:.0f}",
                                         static_cast<double>(counts.json_states) / round_seconds)
                           : std::string()});
             }});
    const auto& latency = rounds_run.latency;
    const auto& p99_ratios = rounds_run.p99_ratios;
    const auto& with_json = rounds_run.total[1];
    const auto& without = rounds_run.total[0];
    const double p99_median = median(p99_ratios);
    fmt::print(
        "\nAll rounds together: p99 {:.0f} µs with JSON, {:.0f} µs without ({:.3f}×; median of "
        "{} pairs {:.3f}×); CPU per request {:.2f} against {:.2f} µs.\n",
        latency[1].p99, latency[0].p99, latency[1].p99 / latency[0].p99, rounds, p99_median,
        with_json.cpu_us_per_request(), without.cpu_us_per_request());
    machine_line(fmt::format(
        R"({{"bench":"mqtt_json_modbus","connections":{},"rounds":{},"req_s_json":{:.0f},"req_s_alone":{:.0f},"p99_us_json":{:.0f},"p99_us_alone":{:.0f},"p99_ratio_median":{:.4f},"cpu_us_json":{:.3f},"cpu_us_alone":{:.3f},"errors_json":{},"errors_alone":{}}})",
        connections, rounds, with_json.per_second(), without.per_second(), latency[1].p99,
        latency[0].p99, p99_median, with_json.cpu_us_per_request(), without.cpu_us_per_request(),
        with_json.errors, without.errors));

    return {
        {"9. ioportd CPU, Sparkplug + JSON ÷ Sparkplug alone, every analog value changing",
         fmt::format("{:.2f} % ÷ {:.2f} % = {:.3f}× (median of {} windows; {:.0f} JSON "
                     "states/s, {:.1f} µs each)",
                     beside_pct, alone_pct, beside_pct / alone_pct, windows, states_per_s,
                     us_per_state),
         "(reported), every output publishing", total.json_states > 0 && total.ddata_beside > 0},
        {"9. Modbus p99 at 64 connections, Sparkplug + JSON ÷ Sparkplug alone",
         fmt::format("median of {} pairs {:.3f}× (all rounds: {:.0f} vs {:.0f} µs)", rounds,
                     p99_median, latency[1].p99, latency[0].p99),
         "<= 1.05×", with_json.errors == 0 && without.errors == 0 && p99_median <= 1.05}};
}

}  // namespace ioport::bench
