// Benchmark 10, the cost curve (issue 42): 1, 2, 4, 8 and 16 links, each a full bus at 115200
// baud on a simulator of its own (ioport-sim on its own pty) with every input word and analog
// channel changing, and every northbound path on at once: a Modbus client polling each unit,
// Sparkplug B and MQTT JSON to a local mosquitto, a /metrics scrape a second. A row per size:
// points read from the devices per second, northbound messages per second, ioportd's CPU and
// RSS, Modbus p99, change → DDATA p99, and the latency of a write of 100 coils made meanwhile.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"
#include "bench/perf/mqtt_broker.hpp"
#include "protocol/sparkplug.hpp"
#include "sim/control_client.hpp"

namespace ioport::bench {
namespace {
// A scope of its own: the benchmarks are built as one unity source.
namespace curve {

constexpr std::string_view group = "curve";
constexpr std::string_view json_prefix = "ioportd/curve";
// Each input module's words move this often on its simulator (ioport-sim --wander): more often
// than a full bus at 115200 baud is read (about 45 ms), so every read carries a change.
constexpr auto wander_period = 20ms;
// The Modbus clients: each unit polled this often, as a SCADA's scan.
constexpr auto modbus_period = 100ms;
// The write made during the load: FC 15, this many coils from coil 0 (dom16 0-6), this often.
constexpr int write_coils = 100;
constexpr auto write_period = 500ms;
// dim16 0 of each link is set by this benchmark (its control socket), not wandered: the change
// whose DDATA is timed.
constexpr ModuleAddress probe{ModuleType::dim16, 0};

// The full bus of issue 6 and the eight dom16 the write reaches.
std::vector<ModuleAddress> curve_bus() {
    auto modules = full_bus();
    const auto outputs = modules_of(ModuleType::dom16);
    modules.insert(modules.end(), outputs.begin(), outputs.end());
    return modules;
}

// What one poll cycle of the bus reads: a point per digital input and per analog channel.
int points_per_cycle(const std::vector<ModuleAddress>& modules) {
    int points = 0;
    for (const auto module : modules) {
        if (is_output(module.type)) continue;
        points += module.type == ModuleType::dim16 || module.type == ModuleType::lim16
                      ? 16
                      : reply_words(module.type);
    }
    return points;
}

double ms(double us) {
    return us / 1000.0;
}

// Run time of each thread of a process, by thread id, with its name.
struct ThreadTime {
    std::string name;
    std::chrono::nanoseconds run{};
};
std::map<int, ThreadTime> thread_times(pid_t pid) {
    std::map<int, ThreadTime> threads;
    std::error_code ec;
    for (const auto& task :
         std::filesystem::directory_iterator(fmt::format("/proc/{}/task", pid), ec)) {
        std::ifstream in(task.path() / "schedstat");
        long long run_ns = 0;
        if (!(in >> run_ns)) continue;
        auto name = read_file(task.path() / "comm");
        while (!name.empty() && name.back() == '\n')
            name.pop_back();
        threads[std::stoi(task.path().filename().string())] = {name,
                                                               std::chrono::nanoseconds(run_ns)};
    }
    return threads;
}

// The client CPU's busy time from /proc/stat (user, nice, system, irq, softirq, steal), and all.
struct CpuTicks {
    unsigned long long busy = 0, total = 0;
};
CpuTicks cpu_ticks(std::optional<int> cpu) {
    std::istringstream stat(read_file("/proc/stat"));
    const auto label = cpu ? fmt::format("cpu{}", *cpu) : std::string("cpu");
    std::string line;
    while (std::getline(stat, line)) {
        std::istringstream fields(line);
        std::string name;
        fields >> name;
        if (name != label) continue;
        std::array<unsigned long long, 8> v{};
        for (auto& x : v)
            fields >> x;
        // user nice system idle iowait irq softirq steal
        return {v[0] + v[1] + v[2] + v[5] + v[6] + v[7],
                v[0] + v[1] + v[2] + v[3] + v[4] + v[5] + v[6] + v[7]};
    }
    return {};
}

// GET `path` on a connection of its own (Connection: close), as a scraper without keep-alive:
// the status (0: no answer within 5 s) and the body's size.
std::pair<unsigned, std::size_t> http_get(std::uint16_t port, std::string_view path) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return {0, 0};
    const timeval timeout{5, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
    ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &timeout, sizeof timeout);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(port);
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    std::string reply;
    if (::connect(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address) == 0) {
        const auto request = fmt::format(
            "GET {} HTTP/1.1\r\nHost: 127.0.0.1\r\nUser-Agent: Prometheus/2.45.0\r\n"
            "Connection: close\r\n\r\n",
            path);
        if (::send(fd, request.data(), request.size(), MSG_NOSIGNAL) ==
            static_cast<ssize_t>(request.size())) {
            std::array<char, 65536> buffer{};
            for (;;) {
                const auto n = ::recv(fd, buffer.data(), buffer.size(), 0);
                if (n <= 0) break;
                reply.append(buffer.data(), static_cast<std::size_t>(n));
            }
        }
    }
    ::close(fd);
    unsigned status = 0;
    if (reply.starts_with("HTTP/1.1 ") && reply.size() > 12)
        status = static_cast<unsigned>(std::atoi(reply.c_str() + 9));
    const auto body = reply.find("\r\n\r\n");
    return {status, body == std::string::npos ? 0 : reply.size() - body - 4};
}

// One row of the table.
struct Row {
    int links = 0;
    bool ran = false;
    std::string why;
    double seconds = 0;
    double points_per_s = 0;
    double transactions_per_s = 0;
    double cycle_ms = 0;
    double ddata_per_s = 0, json_per_s = 0, modbus_per_s = 0;
    double cpu_percent = 0;
    double client_cpu_percent = 0;  // the CPU the simulators, broker and clients share
    double faults_per_s = 0;
    Memory memory;
    Summary modbus_us, ddata_us, write_us, scrape_us;
    int modbus_errors = 0, write_errors = 0, scrape_errors = 0, probes = 0, probes_lost = 0;
    std::vector<std::pair<std::string, double>> threads;  // name (tid), % of a core
    double northbound_per_s() const { return ddata_per_s + json_per_s + modbus_per_s; }
    double cpu_per_10k_points() const {
        return points_per_s > 0 ? cpu_percent / (points_per_s / 10000.0) : 0;
    }
};

// Counts the MQTT side and times the probes' DDATA: a subscriber to everything on the broker.
class Northbound {
  public:
    explicit Northbound(int links) {
        for (int l = 0; l < links; ++l)
            probe_devices_[sparkplug::device_id(fmt::format("hub{}", l), probe)] = l;
    }
    void add(const Received& message) {
        if (message.topic.starts_with(json_prefix)) {
            if (message.topic.ends_with("/state")) ++json_;
            return;
        }
        const auto topic = sparkplug::parse_topic(message.topic);
        if (!topic) return;
        if (topic->type == sparkplug::MessageType::ddata) ++ddata_;
        const bool birth = topic->type == sparkplug::MessageType::dbirth;
        if (topic->type != sparkplug::MessageType::ddata && !birth) return;
        // Only the probes' devices are decoded: this subscriber shares the client CPU.
        const auto found = probe_devices_.find(topic->device);
        if (found == probe_devices_.end()) return;
        const auto payload = sparkplug::decode(message.payload);
        if (!payload) return;
        const std::scoped_lock lock(mutex_);
        if (birth)
            for (const auto& metric : payload->metrics)
                if (metric.name == "word") word_alias_[found->second] = metric.alias;
        for (const auto& metric : payload->metrics) {
            const auto alias = word_alias_.find(found->second);
            const bool word =
                metric.name == "word" ||
                (alias != word_alias_.end() && alias->second && metric.alias == alias->second);
            const auto* value = metric.value ? std::get_if<std::uint64_t>(&*metric.value) : nullptr;
            if (word && value != nullptr) arrived_.try_emplace({found->second, *value}, message.at);
        }
    }
    std::uint64_t ddata() const { return ddata_; }
    std::uint64_t json() const { return json_; }
    bool births(int links) const {
        const std::scoped_lock lock(mutex_);
        return static_cast<int>(word_alias_.size()) == links;
    }
    std::optional<Clock::time_point> arrived(int link, std::uint16_t word) const {
        const std::scoped_lock lock(mutex_);
        const auto found = arrived_.find({link, word});
        if (found == arrived_.end()) return std::nullopt;
        return found->second;
    }

  private:
    std::map<std::string, int, std::less<>> probe_devices_;  // device id → link
    std::atomic<std::uint64_t> ddata_{0}, json_{0};
    mutable std::mutex mutex_;
    std::map<int, std::optional<std::uint64_t>> word_alias_;
    std::map<std::pair<int, std::uint64_t>, Clock::time_point> arrived_;
};

// The Modbus clients: one connection per unit, each reading its unit's whole image every
// modbus_period (raw words, the floats, the discrete inputs); and one connection writing 100
// coils every write_period, to each unit in turn.
struct ModbusSide {
    std::vector<double> reads_us, writes_us;
    int read_errors = 0, write_errors = 0;
    std::uint64_t requests = 0;
};

ModbusSide modbus_side(std::uint16_t port, int links, Clock::time_point from,
                       Clock::time_point to) {
    ModbusSide side;
    std::mutex mutex;
    std::vector<std::thread> threads;
    for (int unit = 1; unit <= links; ++unit)
        threads.emplace_back([&, unit] {
            ModbusConnection connection(port, unit);
            std::vector<double> latency;
            int errors = 0;
            std::uint64_t requests = 0;
            std::array<std::uint16_t, 125> registers{};
            std::array<std::uint8_t, 256> bits{};
            // Spread over the period, so that the units' scans do not all come at once.
            auto next = from + modbus_period * unit / links;
            while (next < to) {
                std::this_thread::sleep_until(next);
                next += modbus_period;
                for (int k = 0; k < 3; ++k) {
                    const auto sent = Clock::now();
                    bool ok = connection.connected();
                    if (ok && k == 0)
                        ok = modbus_read_input_registers(connection.get(), 0, 80,
                                                         registers.data()) == 80;
                    if (ok && k == 1)
                        ok = modbus_read_input_registers(connection.get(), 200, 120,
                                                         registers.data()) == 120;
                    if (ok && k == 2)
                        ok = modbus_read_input_bits(connection.get(), 0, 256, bits.data()) == 256;
                    ++requests;
                    if (ok)
                        latency.push_back(microseconds(Clock::now() - sent));
                    else
                        ++errors;
                }
            }
            const std::scoped_lock lock(mutex);
            side.reads_us.insert(side.reads_us.end(), latency.begin(), latency.end());
            side.read_errors += errors;
            side.requests += requests;
        });
    threads.emplace_back([&] {
        std::vector<std::unique_ptr<ModbusConnection>> connections;
        for (int unit = 1; unit <= links; ++unit)
            connections.push_back(std::make_unique<ModbusConnection>(port, unit));
        std::vector<double> latency;
        int errors = 0;
        std::array<std::uint8_t, write_coils> coils{};
        auto next = from + std::min<Clock::duration>(write_period / 2, (to - from) / 4);
        for (int i = 0; next < to; ++i) {
            std::this_thread::sleep_until(next);
            next += write_period;
            for (std::size_t c = 0; c < coils.size(); ++c)
                coils[c] = static_cast<std::uint8_t>((c + static_cast<std::size_t>(i)) % 2);
            auto& connection = *connections[static_cast<std::size_t>(i % links)];
            const auto sent = Clock::now();
            const bool ok =
                connection.connected() &&
                modbus_write_bits(connection.get(), 0, write_coils, coils.data()) == write_coils;
            if (ok)
                latency.push_back(microseconds(Clock::now() - sent));
            else
                ++errors;
        }
        const std::scoped_lock lock(mutex);
        side.writes_us = std::move(latency);
        side.write_errors = errors;
        side.requests += side.writes_us.size() + static_cast<std::size_t>(errors);
    });
    for (auto& thread : threads)
        thread.join();
    return side;
}

Row measure(const Environment& env, int links, std::chrono::milliseconds window) {
    Row row;
    row.links = links;
    TempDir dir;
    Broker broker(env, dir, env.placement.client_cpu);
    if (!broker.started()) {
        row.why = broker.why();
        return row;
    }
    const auto bus = curve_bus();
    std::vector<std::unique_ptr<SimProcess>> sims;
    std::vector<LinkSpec> specs;
    std::vector<std::string> controls;
    for (int l = 0; l < links; ++l) {
        const auto link = dir / fmt::format("tty{}", l);
        controls.push_back(dir / fmt::format("ctl{}", l));
        sims.push_back(std::make_unique<SimProcess>(
            env, link, bus,
            std::vector<std::string>{
                "--baud", "115200", "--turnaround", "0", "--control", controls.back(), "--wander",
                fmt::format("{}us", std::chrono::microseconds(wander_period).count()), "--still",
                fmt::format("{}:{}", name(probe.type), probe.number)}));
        if (!sims.back()->ready()) {
            row.why = "ioport-sim did not start";
            return row;
        }
        specs.push_back({link, 115200, bus, {}, false});
    }
    Northbound northbound(links);
    Subscriber subscriber(broker.port(), {"#"},
                          [&](const Received& message) { northbound.add(message); });
    const auto more = fmt::format(
        "mqtt:\n  broker: \"mqtt://127.0.0.1:{0}\"\n  group_id: {1}\n  edge_node_id: box\n"
        "mqtt_json:\n  broker: \"mqtt://127.0.0.1:{0}\"\n  topic_prefix: {2}\n",
        broker.port(), group, json_prefix);
    Gateway gateway(env, dir, gateway_yaml(specs, 64, true, more));
    const auto http_port = gateway.started() ? gateway.http_port() : std::uint16_t{0};
    if (!gateway.started() || http_port == 0 ||
        !wait_for([&] { return subscriber.ready(); }, 10s) ||
        !gateway.wait_until_polling(links, 60s) ||
        !wait_for([&] { return northbound.births(links); }, 20s)) {
        row.why = "ioportd did not start, or no birth of every probe";
        fmt::print(stderr, "{} link(s): {}; ioportd's log:\n{}\n", links, row.why, gateway.log());
        return row;
    }
    std::vector<std::unique_ptr<sim::ControlClient>> control;
    for (const auto& socket : controls) {
        control.push_back(std::make_unique<sim::ControlClient>());
        if (auto connected = control.back()->connect(socket); !connected) {
            row.why = connected.error().message;
            return row;
        }
    }

    // Warm up: every path once (a scrape, a write, the clients connected) before the window.
    (void)http_get(http_port, "/metrics");
    const auto from = Clock::now() + (env.quick ? 100ms : 1s);
    const auto to = from + window;
    std::optional<ModbusSide> modbus;
    std::thread clients([&] { modbus = modbus_side(gateway.port(), links, from, to); });
    // The scraper: /metrics once a second.
    std::vector<double> scrapes;
    int scrape_errors = 0;
    std::thread scraper([&] {
        for (auto next = from; next < to; next += 1s) {
            std::this_thread::sleep_until(next);
            const auto sent = Clock::now();
            const auto [status, bytes] = http_get(http_port, "/metrics");
            if (status == 200 && bytes > 0)
                scrapes.push_back(microseconds(Clock::now() - sent));
            else
                ++scrape_errors;
        }
    });
    std::vector<std::unique_ptr<ModbusConnection>> diagnostics;
    for (int unit = 1; unit <= links; ++unit)
        diagnostics.push_back(std::make_unique<ModbusConnection>(gateway.port(), unit));
    const auto read_all = [&] {
        std::vector<Diagnostics> all;
        for (auto& connection : diagnostics)
            all.push_back(read_diagnostics(*connection).value_or(Diagnostics{}));
        return all;
    };

    std::this_thread::sleep_until(from);
    const auto diag_before = read_all();
    const auto cpu_before = cpu_time(gateway.pid());
    const auto threads_before = thread_times(gateway.pid());
    const auto faults_before = minor_faults(gateway.pid());
    const auto client_before = cpu_ticks(env.placement.client_cpu);
    const auto ddata_before = northbound.ddata();
    const auto json_before = northbound.json();
    const auto start = Clock::now();

    // The probes: at random moments 60-140 ms apart, one link's dim16 0 after the other takes a
    // new word through its simulator's control socket; the time before the command is the change.
    // Apart by more than a cycle (register 1001), so that a read sees each change before the
    // next replaces it: a probe without its DDATA is then one lost, not one never read.
    int cycle_us = 0;
    if (const auto d = read_diagnostics(*diagnostics.front())) cycle_us = d->last_cycle_100us * 100;
    const int least_us = std::max(60'000, cycle_us * 3 / 2);
    std::mt19937 random(42);
    std::uniform_int_distribution<int> pause_us(least_us, least_us + 80'000);
    std::vector<std::tuple<int, std::uint16_t, Clock::time_point>> changes;
    for (int i = 0;; ++i) {
        std::this_thread::sleep_for(std::chrono::microseconds(pause_us(random)));
        if (Clock::now() >= to) break;
        const int link = i % links;
        const auto word = static_cast<std::uint16_t>(0x1000 + i);
        const auto at = Clock::now();
        if (control[static_cast<std::size_t>(link)]->command(
                fmt::format("set {}:{} {}", name(probe.type), probe.number, word)))
            changes.emplace_back(link, word, at);
    }
    std::this_thread::sleep_until(to);
    const auto elapsed = seconds(Clock::now() - start);
    const auto diag_after = read_all();
    const auto cpu = cpu_time(gateway.pid()) - cpu_before;
    const auto threads_after = thread_times(gateway.pid());
    const auto faults = minor_faults(gateway.pid()) - faults_before;
    const auto client_after = cpu_ticks(env.placement.client_cpu);
    row.memory = memory(gateway.pid());
    row.ddata_per_s = static_cast<double>(northbound.ddata() - ddata_before) / elapsed;
    row.json_per_s = static_cast<double>(northbound.json() - json_before) / elapsed;
    clients.join();
    scraper.join();

    // The last probe's DDATA may still be on its way.
    if (!changes.empty())
        wait_for(
            [&] {
                return northbound.arrived(std::get<0>(changes.back()), std::get<1>(changes.back()))
                    .has_value();
            },
            1s);
    std::vector<double> ddata_us;
    for (const auto& [link, word, at] : changes) {
        const auto arrived = northbound.arrived(link, word);
        if (arrived)
            ddata_us.push_back(microseconds(*arrived - at));
        else
            ++row.probes_lost;
    }
    row.probes = static_cast<int>(changes.size());

    std::uint64_t cycles = 0, ok = 0;
    for (std::size_t u = 0; u < diag_before.size(); ++u) {
        cycles += diag_after[u].cycles - diag_before[u].cycles;
        ok += diag_after[u].ok - diag_before[u].ok;
    }
    row.ran = true;
    row.seconds = elapsed;
    row.points_per_s = static_cast<double>(cycles) * points_per_cycle(bus) / elapsed;
    row.transactions_per_s = static_cast<double>(ok) / elapsed;
    row.cycle_ms = cycles > 0 ? elapsed * 1000.0 * links / static_cast<double>(cycles) : 0;
    row.cpu_percent = core_percent(cpu, elapsed);
    row.faults_per_s = static_cast<double>(faults) / elapsed;
    if (client_after.total > client_before.total)
        row.client_cpu_percent = 100.0 *
                                 static_cast<double>(client_after.busy - client_before.busy) /
                                 static_cast<double>(client_after.total - client_before.total);
    row.modbus_per_s = static_cast<double>(modbus->requests) / seconds(to - from);
    row.modbus_us = summarize(modbus->reads_us);
    row.modbus_errors = modbus->read_errors;
    row.write_us = summarize(modbus->writes_us);
    row.write_errors = modbus->write_errors;
    row.ddata_us = summarize(std::move(ddata_us));
    row.scrape_us = summarize(std::move(scrapes));
    row.scrape_errors = scrape_errors;
    std::vector<std::pair<std::string, double>> split;
    for (const auto& [tid, after] : threads_after) {
        const auto found = threads_before.find(tid);
        const auto run = after.run - (found == threads_before.end() ? 0ns : found->second.run);
        split.emplace_back(fmt::format("{} ({})", after.name, tid), core_percent(run, elapsed));
    }
    std::sort(split.begin(), split.end(),
              [](const auto& a, const auto& b) { return a.second > b.second; });
    row.threads = std::move(split);
    return row;
}

std::vector<Verdict> run(const Environment& env) {
    const auto sizes = env.quick ? std::vector<int>{1, 2} : env.curve_links;
    const auto window = env.window(10s);
    const auto bus = curve_bus();
    if (!std::filesystem::exists(env.binaries.mosquitto)) {
        fmt::print("\n{}: no mosquitto, benchmark 10 skipped.\n", env.binaries.mosquitto);
        return {};
    }
    fmt::print(
        "\n## 10. The cost curve: 1 to {} links with every path on\n\nEach link a full bus ({} "
        "modules: the 48 of issue 6 and dom16 0-7) at 115200 baud on an ioport-sim of its own "
        "(modelled line timing, turnaround 0, every input word moving every {} ms: --wander), "
        "ioportd on the server CPU with Sparkplug B and MQTT JSON to a local mosquitto, a "
        "Modbus client per unit reading its whole image (input registers 0-79 and 200-319, "
        "discrete inputs 0-255) every {} ms, a /metrics scrape a second, and a write of {} "
        "coils (FC 15, dom16 0-6) every {} ms to each unit in turn; simulators, broker and "
        "clients on the client CPU. A point is a digital input or an analog channel read from a "
        "device ({} a cycle of a bus). Change → DDATA: dim16 0 of a link set through its "
        "simulator's control socket at random moments 60-140 ms apart (more on a cycle slower than "
        "40 ms: 1.5 cycles to 1.5 cycles + 80 ms), to the DDATA carrying it "
        "at a subscriber; it includes the wait for the poll (a cycle). Windows of {:.1f} s.\n",
        sizes.back(), bus.size(), wander_period.count(), modbus_period.count(), write_coils,
        write_period.count(), points_per_cycle(bus), seconds(window));
    std::vector<Row> rows;
    for (const int links : sizes) {
        rows.push_back(measure(env, links, window));
        const auto& r = rows.back();
        if (!r.ran) {
            fmt::print("\n{} link(s): not measured ({}).\n", links, r.why);
            continue;
        }
        fmt::print(
            "\n{} link(s): cycle {:.1f} ms, {:.0f} transactions/s, DDATA {:.0f}/s, JSON states "
            "{:.0f}/s, Modbus {:.0f} requests/s ({} errors), writes {} (errors {}), scrapes {} "
            "(p99 {:.1f} ms, errors {}), probes {} ({} without DDATA), minor faults "
            "{:.0f}/s, client CPU {:.0f} % busy; ioportd's threads:",
            links, r.cycle_ms, r.transactions_per_s, r.ddata_per_s, r.json_per_s, r.modbus_per_s,
            r.modbus_errors, r.write_us.count, r.write_errors, r.scrape_us.count,
            ms(r.scrape_us.p99), r.scrape_errors, r.probes, r.probes_lost, r.faults_per_s,
            r.client_cpu_percent);
        for (std::size_t t = 0; t < std::min<std::size_t>(r.threads.size(), 6); ++t)
            fmt::print(" {} {:.2f} %{}", r.threads[t].first, r.threads[t].second,
                       t + 1 < std::min<std::size_t>(r.threads.size(), 6) ? "," : "");
        fmt::print("\n");
        machine_line(fmt::format(
            R"({{"bench":"cost_curve","links":{},"seconds":{:.2f},"points_per_s":{:.0f},"transactions_per_s":{:.0f},"cycle_ms":{:.2f},"ddata_per_s":{:.1f},"json_per_s":{:.1f},"modbus_per_s":{:.1f},"cpu_pct":{:.3f},"cpu_pct_per_10k_points":{:.3f},"rss_kib":{},"peak_kib":{},"modbus_p99_us":{:.0f},"ddata_p50_ms":{:.2f},"ddata_p99_ms":{:.2f},"write_mean_ms":{:.2f},"write_p99_ms":{:.2f},"writes":{},"write_errors":{},"modbus_errors":{},"probes":{},"probes_lost":{},"faults_per_s":{:.1f},"client_cpu_pct":{:.1f}}})",
            links, r.seconds, r.points_per_s, r.transactions_per_s, r.cycle_ms, r.ddata_per_s,
            r.json_per_s, r.modbus_per_s, r.cpu_percent, r.cpu_per_10k_points(), r.memory.rss_kib,
            r.memory.peak_kib, r.modbus_us.p99, ms(r.ddata_us.p50), ms(r.ddata_us.p99),
            ms(r.write_us.mean), ms(r.write_us.p99), r.write_us.count, r.write_errors,
            r.modbus_errors, r.probes, r.probes_lost, r.faults_per_s, r.client_cpu_percent));
    }

    fmt::print("\n");
    const Table table({"links", "points/s read", "northbound msg/s (DDATA + JSON + Modbus)",
                       "ioportd CPU % of a core", "CPU % per 10k points/s",
                       "per 10k points ÷ 1 link's", "RSS MiB (peak)", "Modbus p99 ms",
                       "change → DDATA p99 ms", "write of 100 coils, mean (p99) ms"});
    // Linear in the links is a constant cost per point read: where the client CPU cannot run
    // every simulator at the line's pace, the links read fewer points each, and the CPU per link
    // would flatter the larger sizes.
    std::optional<double> one_link_cost;
    bool rss_ok = true, cpu_ok = true, all_ran = true;
    double worst_linearity = 0;
    for (const auto& r : rows) {
        if (!r.ran) {
            all_ran = false;
            table.row(
                {fmt::format("{}", r.links), "not measured", r.why, "", "", "", "", "", "", ""});
            continue;
        }
        if (!one_link_cost) one_link_cost = r.cpu_per_10k_points();
        const double linearity = *one_link_cost > 0 ? r.cpu_per_10k_points() / *one_link_cost : 0;
        worst_linearity = std::max(worst_linearity, linearity);
        rss_ok = rss_ok && mib(r.memory.rss_kib) < 32;
        cpu_ok = cpu_ok && r.cpu_per_10k_points() < 3.0;
        table.row({fmt::format("{}", r.links), fmt::format("{:.0f}", r.points_per_s),
                   fmt::format("{:.0f} ({:.0f} + {:.0f} + {:.0f})", r.northbound_per_s(),
                               r.ddata_per_s, r.json_per_s, r.modbus_per_s),
                   fmt::format("{:.1f}", r.cpu_percent),
                   fmt::format("{:.2f}", r.cpu_per_10k_points()), fmt::format("{:.2f}", linearity),
                   fmt::format("{:.1f} ({:.1f})", mib(r.memory.rss_kib), mib(r.memory.peak_kib)),
                   fmt::format("{:.2f}", ms(r.modbus_us.p99)),
                   fmt::format("{:.1f}", ms(r.ddata_us.p99)),
                   fmt::format("{:.0f} ({:.0f})", ms(r.write_us.mean), ms(r.write_us.p99))});
    }
    return {
        {"10. RSS with every path on, every size", all_ran ? "see the table" : "not measured",
         "< 32 MiB", all_ran && rss_ok},
        {"10. CPU per 10,000 points/s read, every size", all_ran ? "see the table" : "not measured",
         "< 3 % (EMQX Neuron's published figure)", all_ran && cpu_ok},
        {"10. CPU per 10,000 points/s ÷ the smallest size's, worst size",
         all_ran ? fmt::format("{:.2f}", worst_linearity) : "not measured", "<= 1.2 (linear)",
         all_ran && worst_linearity <= 1.2}};
}

}  // namespace curve
}  // namespace

std::vector<Verdict> cost_curve(const Environment& env) {
    return curve::run(env);
}

}  // namespace ioport::bench
