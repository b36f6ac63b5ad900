// What the five benchmarks of bench/README.md share: child processes pinned to a CPU (ioportd,
// ioport-sim, the plain libmodbus server), the simulator run inside the benchmark's own process
// (so that its log and the benchmark share one clock), Modbus connections, CPU time and memory of
// a process from /proc, percentiles, and the tables and machine-readable lines they print.
#pragma once

#include <sys/types.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <future>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <modbus/modbus.h>

#include "link/asio.hpp"
#include "protocol/ioport.hpp"
#include "sim/model.hpp"
#include "sim/simulator.hpp"
#include "tests/support/beside_program.hpp"

namespace ioport::bench {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

struct Binaries {
    std::string ioportd = IOPORTD_BINARY;
    std::string sim = IOPORT_SIM_BINARY;
    std::string plain_server = PLAIN_SERVER_BINARY;
    std::string baseline;  // --baseline: an earlier ioportd, measured beside it in 4, 6b and 7b
    // The MQTT broker of benchmark 7 (--mosquitto); without it benchmark 7 says so and skips.
    std::string mosquitto = "/usr/sbin/mosquitto";
    // Benchmark 8 makes its certificates with it, as docs/tls.md tells an operator to.
    std::string openssl = "/usr/bin/openssl";
    // Benchmark 6d-e hashes its password with it, as docs/http.md tells an operator to.
    std::string htpasswd = "/usr/bin/htpasswd";
};

// Where things run. The server under test (ioportd or the plain server) gets a CPU to itself;
// the load clients and the simulators share the other one, so that the server's CPU time and
// its wake-ups are its own. Without two CPUs nothing is pinned.
struct Placement {
    std::optional<int> server_cpu;
    std::optional<int> client_cpu;
};

struct Environment {
    Binaries binaries;
    Placement placement;
    bool quick = false;  // a smoke run: every phase a fraction of a second, figures meaningless
    // Scales the measured windows of a full run.
    double scale = 1.0;
    // Benchmark 6 waits the ten minutes it takes every trend ring to fill, and measures the
    // memory then, rather than only computing it.
    bool fill_trends = false;
    // Benchmark 7c: how many edge nodes, each an ioportd on its own simulator, share one broker
    // (0: skip 7c). Never in a --quick run.
    int fleet = 50;
    // Benchmark 10: the numbers of links, one row each (--links 1,4).
    std::vector<int> curve_links{1, 2, 4, 8, 16};
    std::chrono::milliseconds window(std::chrono::milliseconds full) const;
    // This environment with --baseline's ioportd in place of the one under test.
    Environment baseline() const;
};

void pin_this_thread(std::optional<int> cpu);

// While it lives, idle CPUs poll instead of halting: /dev/cpu_dma_latency (PM QoS) held at 0 µs,
// as cyclictest does and tuned's latency-performance profile sets. On a KVM guest a halted vCPU
// takes tens of µs to wake, and every transaction wakes the simulator, the pty's worker, the
// server and the client: benchmarks 1-4 would measure the hypervisor's wake-ups, which every
// server and raw client pays alike, rather than the software. Idle CPU (benchmark 5) is
// measured without it. Needs root; without the device the benchmarks run as before.
class WakeupLatencyHold {
  public:
    WakeupLatencyHold();
    ~WakeupLatencyHold();
    WakeupLatencyHold(const WakeupLatencyHold&) = delete;
    WakeupLatencyHold& operator=(const WakeupLatencyHold&) = delete;
    // Empty when held, otherwise why not.
    const std::string& failure() const { return failure_; }

  private:
    int fd_ = -1;
    std::string failure_;
};

// A file's contents ("" if it cannot be read).
std::string read_file(const std::string& path);

// A temporary directory, removed with its contents.
class TempDir {
  public:
    TempDir();
    ~TempDir();
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
    std::string operator/(std::string_view name) const { return (path_ / name).string(); }
    const std::filesystem::path& path() const { return path_; }

  private:
    std::filesystem::path path_;
};

// A child process with stdout and stderr in a file. SIGTERM (then SIGKILL) when destroyed.
class Process {
  public:
    Process(const std::vector<std::string>& argv, std::optional<int> cpu,
            const std::string& output_path);
    ~Process();
    Process(const Process&) = delete;
    Process& operator=(const Process&) = delete;

    pid_t pid() const { return pid_; }
    bool running() const;
    // SIGTERM, and the exit status (-1: had to be killed).
    int stop(std::chrono::milliseconds deadline = 5s);
    // Waits for the process to end by itself (a command run to its end), and its exit status
    // (-1: not within `deadline`, then killed).
    int wait(std::chrono::milliseconds deadline);
    std::string output() const;

  private:
    pid_t pid_ = -1;
    std::string output_path_;
};

// Run time of every thread of a process, from /proc/PID/task/*/schedstat (nanoseconds, as the
// scheduler accounts it), or /proc/PID/stat utime + stime where schedstat is missing.
std::chrono::nanoseconds cpu_time(pid_t pid);
// How often the threads of a process went to sleep waiting (voluntary context switches, from
// /proc/PID/task/*/status): a server woken for every request sleeps once per request.
std::uint64_t sleeps(pid_t pid);
// utime + stime of a process from /proc/PID/stat, in clock ticks (10 ms here): the coarse
// figure `top` and process_cpu_seconds_total use, as a check on the schedstat figures.
std::chrono::nanoseconds stat_cpu_time(pid_t pid);

// Minor page faults of a process (/proc/PID/stat field 10): pages it touched for the first time
// since they were mapped. On this guest each costs microseconds, so a buffer that goes back to the
// kernel after every request and is faulted in again shows here and in the CPU time.
std::uint64_t minor_faults(pid_t pid);

// `cpu` used in `seconds`, in percent of one core.
double core_percent(std::chrono::nanoseconds cpu, double seconds);

// The CPU time of several processes over the same `windows` windows of `window` each, for
// ratios between them that the machine's drift cannot skew: before(i) ahead of window i, then
// after(i, each process's CPU in it, its seconds).
struct CpuWindows {
    std::vector<std::chrono::nanoseconds> total;  // per process, every window together
    double seconds = 0;
    double percent(std::size_t process) const;  // of a core
};
CpuWindows cpu_windows(
    const std::vector<pid_t>& pids, int windows, std::chrono::milliseconds window,
    const std::function<void(int)>& before,
    const std::function<void(int, const std::vector<std::chrono::nanoseconds>&, double)>& after);

// Polls `condition` every 5 ms until it holds (true) or `deadline` has passed (false).
template <class Condition>
bool wait_for(Condition condition, std::chrono::milliseconds deadline) {
    const auto until = std::chrono::steady_clock::now() + deadline;
    while (!condition()) {
        if (std::chrono::steady_clock::now() >= until) return false;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return true;
}
struct Memory {
    std::size_t rss_kib = 0;
    std::size_t peak_kib = 0;  // VmHWM: the peak resident set since the process started
};
Memory memory(pid_t pid);
double mib(std::size_t kib);

// --- Buses and configurations ---------------------------------------------------------------

// The full bus of issue 6: 8 each of dim16, acm3p, acm3c, lim16, dccim and dcvim, 48 reads.
std::vector<ModuleAddress> full_bus();
// `count` modules of `type`, numbers 0…count-1.
std::vector<ModuleAddress> modules_of(ModuleType type, int count = modules_per_type);
std::vector<ModuleAddress> every_module();  // all 72: 8 of each of the nine types
std::string hub_argument(const std::vector<ModuleAddress>& modules);  // for ioport-sim --hub

// Bytes on the wire of one transaction with `module`, request and reply, terminators included.
std::size_t transaction_bytes(ModuleAddress module);
// 10 bits a byte (8N1).
std::chrono::nanoseconds wire_time(std::size_t bytes, int baud);

// Modules with analog channels, as the daemon decides which modules keep a trend.
bool is_analog(ModuleType type);
// Those of `modules`.
std::vector<ModuleAddress> analog_of(const std::vector<ModuleAddress>& modules);

struct LinkSpec {
    std::string device;
    int baud = 115200;
    std::vector<ModuleAddress> modules;
    // The input modules' `poll:` (read at most this often); 0: every cycle, as fast as the line.
    std::chrono::milliseconds poll{0};
    // Names, units and scales (gateway.md §6.1) on everything that takes them: a name per
    // module, a name, a unit and a scale per analog channel, a name per digital point. The most
    // an ioportd of issue 27 renders; an earlier build (--baseline) refuses the keys.
    bool tags = false;
};
// `http`: the HTTP side on as well (gateway.md §5.4), on a port of its own choosing. `more`:
// further top-level sections, YAML as it goes into the file (the `mqtt:` of benchmark 7).
// `modbus_more`: further keys of the `modbus:` section, indented by two (the `tls:` of
// benchmark 8); `http_more` the same of the `http:` section (the web_config_file and operators of
// benchmark 6d-e).
std::string gateway_yaml(const std::vector<LinkSpec>& links, int max_connections = 32,
                         bool http = false, std::string_view more = {},
                         std::string_view modbus_more = {}, std::string_view http_more = {});

// --- Modbus ---------------------------------------------------------------------------------

// A libmodbus TCP client.
class ModbusConnection {
  public:
    explicit ModbusConnection(std::uint16_t port, int unit = 1,
                              std::chrono::milliseconds response_timeout = 5s);
    ~ModbusConnection();
    ModbusConnection(const ModbusConnection&) = delete;
    ModbusConnection& operator=(const ModbusConnection&) = delete;

    bool connected() const { return connected_; }
    modbus_t* get() const { return context_; }
    std::optional<std::vector<std::uint16_t>> input_registers(int address, int count);

  private:
    modbus_t* context_ = nullptr;
    bool connected_ = false;
};

// Input registers 1000–1009 of a unit (gateway.md §2.3), u32 high word first.
struct Diagnostics {
    std::uint16_t link_state = 0;
    std::uint16_t last_cycle_100us = 0;
    std::uint32_t cycles = 0;
    std::uint32_t ok = 0;
    std::uint32_t failed = 0;
    std::uint32_t opens = 0;
};
std::optional<Diagnostics> read_diagnostics(ModbusConnection& connection);

// --- The programs under test ----------------------------------------------------------------

// ioportd on a configuration in `dir`, its log in the same place; the port it bound (the
// configuration listens on 127.0.0.1:0) is read from the log.
class Gateway {
  public:
    Gateway(const Environment& env, const TempDir& dir, const std::string& yaml);
    std::uint16_t port() const { return port_; }
    // The HTTP side's port, plain or HTTPS, from the log (0: not started, or no http: section).
    std::uint16_t http_port() const;
    // The Modbus/TCP Security listener's port, from the log (0: not started, or no modbus.tls).
    std::uint16_t tls_port() const;
    pid_t pid() const { return process_.pid(); }
    bool started() const { return port_ != 0; }
    std::string log() const { return process_.output(); }
    int stop() { return process_.stop(); }
    // Waits until each unit has every module online and has completed two poll cycles.
    bool wait_until_polling(int units = 1, std::chrono::milliseconds deadline = 20s) const;

  private:
    Process process_;
    std::uint16_t port_ = 0;
};

// The plain select() libmodbus server of benchmark 4 (plain_server.cpp).
class PlainServer {
  public:
    PlainServer(const Environment& env, const TempDir& dir);
    std::uint16_t port() const { return port_; }
    pid_t pid() const { return process_.pid(); }

  private:
    Process process_;
    std::uint16_t port_ = 0;
};

// ioport-sim in its own process, on the client CPU.
class SimProcess {
  public:
    SimProcess(const Environment& env, const std::string& link,
               const std::vector<ModuleAddress>& modules, const std::vector<std::string>& options);
    const std::string& link() const { return link_; }
    bool ready() const { return ready_; }

  private:
    std::string link_;
    Process process_;
    bool ready_ = false;
};

// The simulator's settings with modelled line timing at `baud` and no turnaround: the time it
// models is then exactly bytes × 10 / baud.
sim::SimulatorSettings timed_line(int baud);

// The simulator's own code (sim/simulator.hpp, as ioport-sim runs it) on a thread of this
// process: its request log then tells on the benchmark's clock when the device received each
// request.
class InProcessSim {
  public:
    InProcessSim(const std::string& link, const std::vector<ModuleAddress>& modules,
                 sim::SimulatorSettings settings, std::optional<int> cpu);
    ~InProcessSim();
    InProcessSim(const InProcessSim&) = delete;
    InProcessSim& operator=(const InProcessSim&) = delete;

    bool ready() const { return ready_; }
    const sim::SimulatorSettings& settings() const { return settings_; }
    // When a log entry's `at` is zero, on this process's steady clock, and how well that is known
    // (the time the simulator's constructor took).
    Clock::time_point origin() const { return origin_; }
    std::chrono::nanoseconds origin_uncertainty() const { return origin_uncertainty_; }
    Clock::time_point at(const sim::LogEntry& entry) const { return origin_ + entry.at; }

    std::vector<sim::LogEntry> take_log();
    // Sets an input module's raw words at once, on the simulator's thread, and returns when it
    // did, on this process's clock: the moment the device's input changed.
    Clock::time_point set_values(ModuleAddress module, std::vector<std::uint16_t> words);
    // How late the simulator's answers went out against their modelled end since the last call.
    sim::AnswerErrors take_answer_errors();
    // Every `period`, sets each of `modules` (inputs with one word) to a new value, a counter, so
    // that every reading of a module tells which one it was.
    void tick_values(std::vector<ModuleAddress> modules, std::chrono::microseconds period);
    // The same for input modules of any number of words: every `period`, each word of each of
    // `modules` moves to a value it did not have, as the analog inputs of a plant never hold
    // still. Instead of tick_values, not beside it.
    void wander(std::vector<ModuleAddress> modules, std::chrono::microseconds period);

  private:
    template <class F>
    auto on_sim_thread(F f) -> decltype(f());
    void tick();

    sim::SimulatorSettings settings_;
    asio::io_context io_{1};
    asio::executor_work_guard<asio::io_context::executor_type> work_;
    sim::DeviceModel model_;
    std::optional<sim::Simulator> simulator_;
    Clock::time_point origin_;
    std::chrono::nanoseconds origin_uncertainty_{};
    asio::steady_timer ticker_;
    std::vector<ModuleAddress> ticked_;
    std::chrono::microseconds tick_period_{};
    std::uint16_t tick_value_ = 0;
    bool every_word_ = false;  // wander(), not tick_values()
    bool ready_ = false;
    std::thread thread_;
};

// --- The pty's own limit -------------------------------------------------------------------

struct RawRate {
    double per_second = 0;
    double cpu_us_per_transaction = 0;  // of the raw client
    std::uint64_t failed = 0;
};
// A minimal client of the simulator: blocking write() and read() until the CR, the requests of
// `modules` in order, over and over for `window`, on a thread pinned to `cpu`.
RawRate raw_ping_pong(const std::string& link, const std::vector<ModuleAddress>& modules,
                      std::chrono::milliseconds window, std::optional<int> cpu);

// One write of benchmark 3, ioportd's or the raw client's: when it was sent and answered.
struct TimedWrite {
    Clock::time_point sent, answered;
    std::uint16_t word = 0;  // the output word commanded
    bool ok = false;
};
// The floor of benchmark 3: the same minimal client polls `modules`, and `count` times, at
// random moments 2-10 ms apart, this thread hands it a command to `target` (an output module),
// which it sends between two transactions, as ioportd does with a Modbus write. No TCP, no
// gateway: what is left is the pty, the simulator and the machine's wake-ups.
std::vector<TimedWrite> raw_writes(const std::string& link,
                                   const std::vector<ModuleAddress>& modules, ModuleAddress target,
                                   int count, std::optional<int> cpu);

// --- Figures --------------------------------------------------------------------------------

struct Summary {
    std::size_t count = 0;
    double mean = 0, min = 0, p50 = 0, p99 = 0, p999 = 0, max = 0;
};
// Nearest-rank percentiles.
Summary summarize(std::vector<double> values);
// The lower median (of an even count, the smaller middle value); 0 of none.
double median(std::vector<double> values);

double microseconds(std::chrono::nanoseconds d);
double seconds(Clock::duration d);

// A Markdown table, printed as it is built up.
class Table {
  public:
    explicit Table(std::vector<std::string> header);
    void row(const std::vector<std::string>& cells) const;

  private:
    std::size_t columns_;
};

// One result against its target, for the closing summary and the machine-readable lines.
struct Verdict {
    std::string benchmark;
    std::string figure;  // what was measured, as printed
    std::string target;
    bool met = false;
};

// "BENCH {json}" on a line of its own.
void machine_line(const std::string& json);

std::string yes_no(bool met);

}  // namespace ioport::bench
