// Benchmark 7h, what Sparkplug templates cost and save (issue 41, gateway.md §7.2):
// a. the demo's bus (one module of each type but acm3c) at 115200 baud, every analog channel
//    moving all the time; two ioportd side by side on the same changing input and one local
//    mosquitto, "flat" an edge node as §5.5 (templates off) and "templates" the same with
//    `templates: true`: the bytes of a DDATA, ioportd's CPU per change (a metric or a member that
//    went out) and their ratio, over the same windows;
// b. the births of 8 links × 72 modules, flat and with templates, one ioportd after the other:
//    the NBIRTH (the definitions are there) and every DBIRTH, in bytes.
#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <thread>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"
#include "bench/perf/mqtt_broker.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::bench {
namespace {

// The demo's hub (config/ioportd-sim.yaml), as benchmark 9 runs it.
std::vector<ModuleAddress> demo_hub() {
    return {{ModuleType::dim16, 0}, {ModuleType::dom16, 0}, {ModuleType::acm3p, 0},
            {ModuleType::lim16, 0}, {ModuleType::rgbdm, 0}, {ModuleType::mux8m, 0},
            {ModuleType::dccim, 0}, {ModuleType::dcvim, 0}};
}

std::string node_yaml(std::uint16_t port, std::string_view node, std::string_view lines) {
    return fmt::format(
        "mqtt:\n  broker: \"mqtt://127.0.0.1:{}\"\n  group_id: bench\n  edge_node_id: {}\n{}", port,
        node, lines);
}

// What a subscriber saw of each node: DDATA (messages, payload bytes, bytes with the topic, the
// changes they carried: flat metrics, or an instance's members), NBIRTH and DBIRTH bytes.
struct NodeCounts {
    std::uint64_t ddata = 0, payload_bytes = 0, bytes = 0, changes = 0;
    std::uint64_t nbirth_bytes = 0, dbirths = 0, dbirth_bytes = 0;
    NodeCounts operator-(const NodeCounts& o) const {
        return {ddata - o.ddata, payload_bytes - o.payload_bytes,
                bytes - o.bytes, changes - o.changes,
                nbirth_bytes,    dbirths,
                dbirth_bytes};
    }
};

class NodeTally {
  public:
    void add(const Received& message) {
        const auto topic = sparkplug::parse_topic(message.topic);
        if (!topic) return;
        const std::scoped_lock lock(mutex_);
        auto& node = nodes_[topic->node];
        switch (topic->type) {
            case sparkplug::MessageType::nbirth:
                node.nbirth_bytes = message.payload.size();
                node.dbirths = 0;
                node.dbirth_bytes = 0;
                break;
            case sparkplug::MessageType::dbirth:
                ++node.dbirths;
                node.dbirth_bytes += message.payload.size();
                break;
            case sparkplug::MessageType::ddata: {
                ++node.ddata;
                node.payload_bytes += message.payload.size();
                node.bytes += message.topic.size() + message.payload.size();
                const auto payload = sparkplug::decode(message.payload);
                if (payload) node.changes += sparkplug::to_flat(payload->metrics).size();
                break;
            }
            case sparkplug::MessageType::ndeath:
            case sparkplug::MessageType::ddeath:
            case sparkplug::MessageType::ndata:
            case sparkplug::MessageType::ncmd:
            case sparkplug::MessageType::dcmd:
            case sparkplug::MessageType::state:
                break;
        }
    }
    NodeCounts counts(const std::string& node) const {
        const std::scoped_lock lock(mutex_);
        const auto found = nodes_.find(node);
        return found == nodes_.end() ? NodeCounts{} : found->second;
    }

  private:
    mutable std::mutex mutex_;
    std::map<std::string, NodeCounts, std::less<>> nodes_;
};

double per(std::uint64_t what, std::uint64_t each) {
    return static_cast<double>(what) / static_cast<double>(std::max<std::uint64_t>(each, 1));
}

// --- a. DDATA and CPU of two edge nodes on the same input ----------------------------------------

// Two ways to configure the edge node, compared: `base` and `other`, each a name (its node id
// too) and the lines it adds under mqtt:.
struct Comparison {
    std::string id;     // "7h"
    std::string title;  // of the section
    std::string what;   // the paragraph's account of the two
    std::string base, base_lines, other, other_lines;
};

std::vector<Verdict> compare_nodes(const Environment& env, Broker& broker, const Comparison& c) {
    const auto bus = demo_hub();
    const auto analog = analog_of(bus);
    const auto period = 5ms;
    fmt::print(
        "\n### {}. {}: DDATA and CPU, every analog value changing\n\nThe demo's bus ({} "
        "modules, names, units and scales on every one) at 115200 baud (modelled, simulated in "
        "this process), its {} analog modules' every channel moving every {} ms. Two ioportd on "
        "the server CPU on the same changing input, both edge nodes on one local mosquitto "
        "(client CPU): {} Both run throughout: their CPU is measured over the same windows. A "
        "change is a metric or a template member that went out.\n",
        c.id, c.title, bus.size(), analog.size(), period.count(), c.what);
    NodeTally tally;
    Subscriber subscriber(broker.port(), {"spBv1.0/bench/#"},
                          [&](const Received& message) { tally.add(message); });
    TempDir dir_base, dir_other;
    InProcessSim sim_base(dir_base / "tty", bus, timed_line(115200), env.placement.client_cpu);
    InProcessSim sim_other(dir_other / "tty", bus, timed_line(115200), env.placement.client_cpu);
    const auto link = [&](const TempDir& d) { return LinkSpec{d / "tty", 115200, bus, {}, true}; };
    Gateway base(
        env, dir_base,
        gateway_yaml({link(dir_base)}, 300, false, node_yaml(broker.port(), c.base, c.base_lines)));
    Gateway other(env, dir_other,
                  gateway_yaml({link(dir_other)}, 300, false,
                               node_yaml(broker.port(), c.other, c.other_lines)));
    if (!sim_base.ready() || !sim_other.ready() || !subscriber.ready() || !base.started() ||
        !other.started() || !base.wait_until_polling() || !other.wait_until_polling() ||
        !wait_for(
            [&] {
                return tally.counts(c.base).dbirths >= bus.size() &&
                       tally.counts(c.other).dbirths >= bus.size();
            },
            10s))
        return {{fmt::format("{}. {}", c.id, c.title), "ioportd did not start", "", false}};
    sim_base.wander(analog, period);
    sim_other.wander(analog, period);
    std::this_thread::sleep_for(env.quick ? 100ms : 1s);

    const int windows = env.quick ? 1 : 5;
    const auto window = env.window(3s);
    const Table table({"window", fmt::format("{}, CPU", c.base), fmt::format("{}, CPU", c.other),
                       fmt::format("{} ÷ {}", c.other, c.base), fmt::format("{} B/DDATA", c.base),
                       fmt::format("{} B/DDATA", c.other), fmt::format("{} changes/s", c.base),
                       fmt::format("{} changes/s", c.other)});
    NodeCounts before_base, before_other, total_base, total_other;
    std::vector<double> ratios;
    const auto cpu = cpu_windows(
        {base.pid(), other.pid()}, windows, window,
        [&](int) {
            before_base = tally.counts(c.base);
            before_other = tally.counts(c.other);
        },
        [&](int i, const std::vector<std::chrono::nanoseconds>& used, double s) {
            const auto b = tally.counts(c.base) - before_base;
            const auto o = tally.counts(c.other) - before_other;
            const double base_pct = core_percent(used[0], s);
            const double other_pct = core_percent(used[1], s);
            ratios.push_back(other_pct / base_pct);
            table.row({fmt::format("{}", i + 1), fmt::format("{:.2f} %", base_pct),
                       fmt::format("{:.2f} %", other_pct), fmt::format("{:.3f}", ratios.back()),
                       fmt::format("{:.1f}", per(b.payload_bytes, b.ddata)),
                       fmt::format("{:.1f}", per(o.payload_bytes, o.ddata)),
                       fmt::format("{:.0f}", static_cast<double>(b.changes) / s),
                       fmt::format("{:.0f}", static_cast<double>(o.changes) / s)});
            for (auto [total, delta] : {std::pair{&total_base, b}, std::pair{&total_other, o}}) {
                total->ddata += delta.ddata;
                total->payload_bytes += delta.payload_bytes;
                total->bytes += delta.bytes;
                total->changes += delta.changes;
            }
        });
    const double base_bytes = per(total_base.payload_bytes, total_base.ddata);
    const double other_bytes = per(total_other.payload_bytes, total_other.ddata);
    const double base_us = microseconds(cpu.total[0]) / std::max(1.0, double(total_base.changes));
    const double other_us = microseconds(cpu.total[1]) / std::max(1.0, double(total_other.changes));
    fmt::print(
        "\nAll windows ({:.1f} s): a DDATA is {:.1f} B {}, {:.1f} B {} ({:.3f}×; with the topic "
        "{:.1f} and {:.1f} B); {:.1f} and {:.1f} changes per DDATA; ioportd's CPU per change "
        "(all of its CPU, polling included, over the changes it published) {:.2f} µs {}, "
        "{:.2f} µs {} ({:.3f}×); CPU {} ÷ {} {:.3f}× (median of the windows {:.3f}×).\n",
        cpu.seconds, base_bytes, c.base, other_bytes, c.other, other_bytes / base_bytes,
        per(total_base.bytes, total_base.ddata), per(total_other.bytes, total_other.ddata),
        per(total_base.changes, total_base.ddata), per(total_other.changes, total_other.ddata),
        base_us, c.base, other_us, c.other, other_us / base_us, c.other, c.base,
        cpu.percent(1) / cpu.percent(0), median(ratios));
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_{}_{}","seconds":{:.2f},"ddata_base":{},"ddata_other":{},"bytes_per_ddata_base":{:.1f},"bytes_per_ddata_other":{:.1f},"bytes_ratio":{:.4f},"changes_base":{},"changes_other":{},"us_per_change_base":{:.3f},"us_per_change_other":{:.3f},"cpu_per_change_ratio":{:.4f},"cpu_base_pct":{:.3f},"cpu_other_pct":{:.3f},"cpu_ratio_median":{:.4f}}})",
        c.base, c.other, cpu.seconds, total_base.ddata, total_other.ddata, base_bytes, other_bytes,
        other_bytes / base_bytes, total_base.changes, total_other.changes, base_us, other_us,
        other_us / base_us, cpu.percent(0), cpu.percent(1), median(ratios)));
    return {{fmt::format("{}. bytes per DDATA, {} ÷ {}", c.id, c.other, c.base),
             fmt::format("{:.1f} B ÷ {:.1f} B = {:.3f}×", other_bytes, base_bytes,
                         other_bytes / base_bytes),
             "(reported)", total_base.ddata > 0 && total_other.ddata > 0},
            {fmt::format("{}. ioportd CPU per change, {} ÷ {}", c.id, c.other, c.base),
             fmt::format("{:.2f} µs ÷ {:.2f} µs = {:.3f}×", other_us, base_us, other_us / base_us),
             "(reported)", total_base.changes > 0 && total_other.changes > 0}};
}

// --- b. The births of 8 links × 72 modules
// ---------------------------------------------------------

struct Births {
    std::uint64_t nbirth = 0, dbirths = 0, dbirth_bytes = 0;
    bool complete = false;
};

Births births_of(const Environment& env, Broker& broker, bool templates) {
    NodeTally tally;
    const auto node = templates ? "big-templates" : "big-flat";
    Subscriber subscriber(broker.port(), {"spBv1.0/bench/#"},
                          [&](const Received& message) { tally.add(message); });
    TempDir dir;
    const auto modules = every_module();
    std::vector<std::unique_ptr<InProcessSim>> sims;
    std::vector<LinkSpec> links;
    bool ready = subscriber.ready() || wait_for([&] { return subscriber.ready(); }, 5s);
    for (int i = 0; i < 8; ++i) {
        const auto tty = dir / fmt::format("tty{}", i);
        sims.push_back(std::make_unique<InProcessSim>(tty, modules, timed_line(115200),
                                                      env.placement.client_cpu));
        ready = ready && sims.back()->ready();
        links.push_back({tty, 115200, modules, {}, true});
    }
    Gateway gateway(
        env, dir,
        gateway_yaml(links, 300, false,
                     node_yaml(broker.port(), node, templates ? "  templates: true\n" : "")));
    const auto expected = 8 * modules.size();
    Births births;
    births.complete = ready && gateway.started() && gateway.wait_until_polling(8, 60s) &&
                      wait_for([&] { return tally.counts(node).dbirths >= expected; }, 30s);
    const auto counts = tally.counts(node);
    births.nbirth = counts.nbirth_bytes;
    births.dbirths = counts.dbirths;
    births.dbirth_bytes = counts.dbirth_bytes;
    gateway.stop();
    return births;
}

std::vector<Verdict> birth_size(const Environment& env, Broker& broker) {
    fmt::print(
        "\n### 7h. Templates: the births of 8 links × 72 modules\n\nOne ioportd on 8 links of "
        "72 modules each (every type, 8 of each; names, units and scales on all), flat and then "
        "with `templates: true`: the NBIRTH (with templates it carries the 9 definitions) and "
        "every DBIRTH, payload bytes.\n\n");
    const auto flat = births_of(env, broker, false);
    const auto templates = births_of(env, broker, true);
    const Table table({"", "NBIRTH B", "DBIRTHs", "DBIRTH B, all", "B per DBIRTH", "all births B"});
    for (const auto& [what, b] : {std::pair{"flat", flat}, std::pair{"templates", templates}})
        table.row({what, fmt::format("{}", b.nbirth), fmt::format("{}", b.dbirths),
                   fmt::format("{}", b.dbirth_bytes),
                   fmt::format("{:.0f}", per(b.dbirth_bytes, b.dbirths)),
                   fmt::format("{}", b.nbirth + b.dbirth_bytes)});
    const double nbirth_ratio = per(templates.nbirth, flat.nbirth);
    const double all_ratio =
        per(templates.nbirth + templates.dbirth_bytes, flat.nbirth + flat.dbirth_bytes);
    fmt::print("\nNBIRTH templates ÷ flat {:.2f}×; every birth together {:.3f}×.\n", nbirth_ratio,
               all_ratio);
    machine_line(fmt::format(
        R"({{"bench":"sparkplug_templates_births","links":8,"modules_per_link":72,"nbirth_flat":{},"nbirth_templates":{},"dbirths_flat":{},"dbirths_templates":{},"dbirth_bytes_flat":{},"dbirth_bytes_templates":{},"all_births_ratio":{:.4f}}})",
        flat.nbirth, templates.nbirth, flat.dbirths, templates.dbirths, flat.dbirth_bytes,
        templates.dbirth_bytes, all_ratio));
    return {{"7h. NBIRTH of 8 links × 72 modules, templates against flat",
             fmt::format("{} B against {} B ({:.2f}×); every birth {:.3f}×", templates.nbirth,
                         flat.nbirth, nbirth_ratio, all_ratio),
             "(reported), every DBIRTH", flat.complete && templates.complete}};
}

}  // namespace

std::vector<Verdict> sparkplug_templates(const Environment& env) {
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: benchmark 7h skipped.\n", broker.why());
        return {};
    }
    auto verdicts = compare_nodes(
        env, broker,
        {.id = "7h",
         .title = "Templates",
         .what = "\"flat\" as gateway.md §5.5, \"templates\" with `templates: true` (§7.2).",
         .base = "flat",
         .base_lines = "",
         .other = "templates",
         .other_lines = "  templates: true\n"});
    for (auto& verdict : birth_size(env, broker))
        verdicts.push_back(std::move(verdict));
    return verdicts;
}

std::vector<Verdict> sparkplug_relay(const Environment& env) {
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        fmt::print("\n{}: benchmark 7i skipped.\n", broker.why());
        return {};
    }
    return compare_nodes(
        env, broker,
        {.id = "7i",
         .title = "MQTT 3.1.1 through the relay",
         .what = "\"mqtt5\" with `protocol: \"5\"` (libmosquitto on the broker's socket), "
                 "\"mqtt311\" with `protocol: \"3.1.1\"` (libmosquitto through the relay on "
                 "loopback, which reads what the broker sends through the 64 KiB bound; "
                 "gateway.md §7.5).",
         .base = "mqtt5",
         .base_lines = "  protocol: \"5\"\n",
         .other = "mqtt311",
         .other_lines = "  protocol: \"3.1.1\"\n"});
}

}  // namespace ioport::bench
