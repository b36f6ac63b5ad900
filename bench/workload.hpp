// Modbus clients that read and write through ioportd while the simulated hub's state is tracked,
// and a checker that holds every answer against what the simulated device really did. Shared by
// the fault tests (tests/integration/fault_test.cpp) and the soak (bench/soak.cpp).
//
// What is checked, from gateway.md §3–4 (times are the client's: `sent` just before a request
// goes out, `received` just after its response came; the simulator's log times are on the same
// CLOCK_MONOTONIC, so they compare exactly):
//
//   Reads. A value served for a module is a state the device really had before `received`:
//     - inputs: one of the states the workload set in the simulator (every state is unique per
//       module, all words of a module together, so a late answer of another module, a garbled
//       frame or a mix of two answers is caught), and, for one client, never older than one it
//       was served before (the image does not go back in time);
//     - outputs: a value the device was commanded and acknowledged with "1" (or its power-on
//       0), and a confirmed one: `initial` or a value some client's write was acknowledged for.
//       A write answered 04/0B may have reached the device (its acknowledgement was late), but
//       gateway.md says the image keeps the last confirmed value.
//   Writes. Every write is answered: normally, or with 04 (error ack) or 0B (no answer, port
//     closed); never left without a response or answered with another exception. A write
//     answered normally reached the device: the simulator applied a command carrying the
//     written bits between `sent` and `received`. A write answered 04/0B never becomes desired
//     state: outside the windows of its owner's writes, every command the device applies
//     carries the last confirmed value (refreshes and restores after a reopen included); only
//     a request spanning two modules may leave either value after an exception (the module that
//     acknowledged keeps its value, gateway.md §4). The write's own transmissions may still
//     reach the device after the exception (the gateway gave up waiting for them; a starved
//     simulator reads them seconds late): at most retries + 1 of them, and never after anything
//     the gateway sent later. That is judged by the order of the line, never by how late the
//     device read them (LateTransmissions in workload.cpp).
//     A write answered normally stays the device's state until a later write of its owner,
//     or until the safe state of a communication loss declared after it reached the gateway
//     (below): a command carrying anything else meanwhile overwrote it, a lost write too.
//   Communication loss (gateway.md §5.3, with comm_loss_timeout set). The gateway may declare it
//     only after a silence: a moment t is possible when no request lies wholly within
//     (t - timeout, t] (a request reached the gateway between `sent` and `received`). From the
//     start of such a silence on, the safe value is a value somebody asked for (the gateway),
//     until a write sent after the silence ended replaces it. Of the writes that reached the
//     gateway before it declared the loss, the one in flight finishes and the others are
//     dropped (answered 0B, never sent); then the safe state: an acknowledged write sent well
//     before the silence (half a timeout: it reached the gateway before) whose value first
//     reaches the device after the safe push began is a wrong value.
//     Once the push began (seen on a module whose safe word nobody writes), or once a silence
//     was confirmed (the first request after it read 1020 = 1) and the gateway had time for one
//     transaction more, the values from before the loss are gone: the desired state is safe,
//     and refreshes and restores after a reopen carry it. Register 1020 reads 1 only for the
//     first request after a possible loss: never once another request reached the gateway
//     after the silence ended (the workload's diagnostics reads include it).
//
// Every output bit has one writer (one client owns each write job), so "the last confirmed
// value" is known without guessing how concurrent writes were ordered.
#pragma once

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "protocol/error.hpp"
#include "protocol/ioport.hpp"
#include "sim/control_client.hpp"

namespace ioport::bench {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

// The hub every workload runs against: five input modules, six output modules.
// For ioport-sim --hub:
std::string hub_sim_modules();
// A links: entry of ioportd's configuration for that hub on `device`. Every output module has a
// `safe` value other than its `initial` (what it is set to at a communication loss, when
// modbus.comm_loss_timeout is on); the workload's clients never write the safe words of dom16 0,
// 2 and 3, so the device applying one of those is the gateway's safe state.
std::string hub_link_yaml(const std::string& device, std::chrono::milliseconds timeout, int retries,
                          std::chrono::milliseconds refresh = 300ms);

struct WorkloadSettings {
    std::uint16_t port = 0;   // ioportd's Modbus TCP port on 127.0.0.1
    std::string sim_control;  // the simulator's control socket
    int clients = 8;
    // A client pauses between its requests for a random time up to this.
    std::chrono::microseconds pause = 2ms;
    double write_share = 0.3;  // of the requests of a client that owns write jobs
    std::chrono::milliseconds input_period = 20ms;  // every input module gets a new state
    // A client's wait for any answer: a hang's bound, not a latency target. A write waits for
    // the device's confirmation, behind the writes queued before it; on a busy machine the
    // simulator was seen to read nothing for seconds, and 16 writes queued behind a module
    // answering 30 ms late then took more than 5 s.
    std::chrono::milliseconds response_timeout = 30s;
    std::uint64_t seed = 1;
    int retries = 1;  // the link's: how many times a write may be sent again
    std::chrono::milliseconds timeout = 50ms;  // the link's, per attempt
    // false: nobody here writes dom16 0 and nothing about it is checked (a test writes it).
    bool write_dom16_0 = true;
    // The gateway's modbus.comm_loss_timeout; 0 (off): no safe value may ever reach the device.
    std::chrono::milliseconds comm_loss_timeout{0};
    // What a busy machine may add to a step of the gateway or the simulator: the gateway's
    // timer firing, the simulator reading a command. A silence lasts this much past the
    // timeout, so that the loss was declared before its first request.
    std::chrono::milliseconds slack = 250ms;
};

struct Latency {
    std::chrono::microseconds max{};
    std::chrono::microseconds p99{};
    std::uint64_t count = 0;
};

struct Report {
    std::uint64_t reads = 0;
    std::uint64_t reads_ok = 0;
    std::uint64_t reads_stale = 0;  // 0B: a module not online
    std::uint64_t writes = 0;
    std::uint64_t writes_acked = 0;
    std::uint64_t writes_04 = 0;
    std::uint64_t writes_0b = 0;
    std::uint64_t transport_errors = 0;       // no response at all: timeout, reset, refused
    std::uint64_t unexpected_exceptions = 0;  // one the request could never earn
    std::uint64_t wrong_values = 0;           // a read served what the device never had
    std::uint64_t lost_writes = 0;            // acknowledged, never applied by the device
    std::uint64_t failed_writes_pushed = 0;   // answered 04/0B, later sent as desired state
    std::uint64_t unanswered_writes = 0;      // neither acknowledged nor an exception
    // Answered 04/0B, yet the device applied the write's own last transmission after the
    // answer (see LateTransmissions in workload.cpp): what a client must expect, not an error.
    std::uint64_t failed_writes_applied_late = 0;
    std::uint64_t transactions = 0;      // on the serial line (the simulator's log)
    std::uint64_t commands_applied = 0;  // output commands the device acknowledged
    std::uint64_t input_states = 0;      // states the workload gave the input modules
    // Communication loss (gateway.md §5.3), when the workload knows the timeout.
    std::uint64_t silences = 0;                     // made by silence()
    std::uint64_t silences_signalled = 0;           // the first request after it read 1020 = 1
    std::uint64_t silences_cleared = 0;             // the second one read 0
    std::uint64_t writes_in_flight_at_silence = 0;  // clients waiting for a write's answer then
    // Output modules the device saw set to their safe value after a possible comm loss (the
    // push itself, or the first refresh or restore carrying it), once per module and silence.
    std::uint64_t safe_pushes = 0;
    // Silences of at least the timeout in the clients' requests (possible comm losses): the
    // workload's own, and any the machine made by starving every client at once.
    std::uint64_t possible_losses = 0;
    Latency read_latency;
    Latency write_latency;
    std::vector<std::string> problems;  // the first ones, described

    std::uint64_t requests() const { return reads + writes; }
    // Nothing wrong served, nothing lost, every request answered.
    bool clean() const;
    std::string summary() const;
};

// Time since start on the simulator's clock → our clock.
class SimClock {
  public:
    SimClock() = default;
    explicit SimClock(Clock::time_point start) : start_(start) {}
    Clock::time_point at(std::int64_t micros_since_start) const {
        return start_ + std::chrono::microseconds(micros_since_start);
    }

  private:
    Clock::time_point start_{};
};
// Asks the simulator for its start ("clock").
Result<SimClock> sim_clock(const std::string& control);

class Workload {
  public:
    explicit Workload(WorkloadSettings settings);
    ~Workload();
    Workload(const Workload&) = delete;
    Workload& operator=(const Workload&) = delete;

    // Connects to the simulator, starts the input driver, the clients and the checker.
    Result<> start();
    // Stops everything, checks what is left; the final report.
    Report finish();
    // What has been checked so far.
    Report snapshot() const;
    // Requests completed so far (checked or not).
    std::uint64_t completed() const { return completed_.load(); }
    // Some client waits for the answer to a write now.
    bool write_in_flight() const;
    // Writes answered with an exception so far (checked or not).
    std::uint64_t writes_failed() const;

    // A communication loss (gateway.md §5.3; needs settings.comm_loss_timeout): every client
    // stops sending (a write it waits for is still answered, and applied first); nothing is
    // sent until the timeout and a margin have passed since the last request, and `length`
    // since the last answer; then the first request is a read of 1020 from a connection of the
    // workload's own (must read 1), then a second (must read 0), then the clients go on.
    // `meanwhile` runs once the clients are held, given the moment they were (a scenario's fault
    // during the loss). Both reads are checked like the rest; a first read other than 1 is a
    // wrong value.
    struct Silence {
        int writes_in_flight = 0;            // clients waiting for a write's answer when held
        std::chrono::milliseconds length{};  // from the last request sent to the first after
        int first = -1;                      // 1020 as the first request after it read it
        int second = -1;                     // and the second; -1: no answer
    };
    Result<Silence> silence(std::chrono::milliseconds length,
                            const std::function<void(Clock::time_point)>& meanwhile = {});

    struct Op;
    struct Target;
    struct InputState {
        Clock::time_point set_after;   // the "set" command went out
        Clock::time_point set_before;  // its reply came
        std::array<std::uint16_t, 3> words{};
    };

  private:
    // A request the device read, in the order it read them (the order the gateway sent them: the
    // line is one queue).
    struct Applied {
        Clock::time_point at;
        int module;  // an output module of `modules`; -1: any other request (a poll read)
        std::uint16_t value;
        bool applied;  // an output command the device acknowledged with "1"
    };
    // A stretch of time in which the gateway may have declared a communication loss: no request
    // lies wholly within the timeout before any moment of it.
    struct LossPeriod {
        Clock::time_point from;
        std::optional<Clock::time_point> until;      // a request certainly reached the gateway then
        std::optional<Clock::time_point> push_seen;  // the safe push was seen beginning
        std::uint32_t modules_pushed = 0;            // bit per module: safe value seen
    };
    struct Expiry {
        Clock::time_point at;
        std::size_t period;
        Clock::time_point boundary;  // writes sent from then on are after the loss
    };

    void run_client(int index);
    void run_inputs();
    void run_checker();
    // The rest with check_mutex_ held.
    void check();
    void check_read(int client, const Op& op);
    bool checked(int module) const;
    void read_request(Target& target, const Applied& request);
    void apply_command(Target& target, Clock::time_point at, std::uint16_t value);
    void fence(Clock::time_point sent);
    void finalize_windows(Target& target, Clock::time_point until);
    void finalize_windows_before(Target& target, Clock::time_point at);
    bool loss_on() const { return settings_.comm_loss_timeout.count() > 0; }
    void record_request(const Op& op);
    void find_loss_periods(Clock::time_point horizon);
    void advance_to(Clock::time_point at);
    void activate(std::size_t period);
    void expire(const Expiry& expiry);
    void push_began(Clock::time_point at);
    void count_safe_push(const Applied& command);
    void check_loss_register(int client, const Op& op);
    void problem(std::uint64_t Report::*counter, std::string text);
    Report current_report() const;

    WorkloadSettings settings_;
    SimClock sim_clock_;
    std::atomic<bool> stop_{false};
    std::atomic<bool> inputs_stop_{false};
    std::atomic<std::uint64_t> completed_{0};
    std::atomic<int> write_in_flight_{0};
    std::atomic<std::uint64_t> writes_failed_{0};
    Clock::time_point started_ = Clock::now();
    std::vector<std::thread> clients_;
    // silence(): clients wait here before each request while it is closed.
    std::mutex gate_mutex_;
    std::condition_variable gate_;
    bool gate_closed_ = false;
    std::thread inputs_;
    std::thread checker_;

    // Per client: the send time of the request in flight (max when none), and finished ops. One
    // more, the last, for silence()'s reads.
    struct ClientSlot;
    std::vector<std::unique_ptr<ClientSlot>> slots_;

    // The input modules' states, written by the input driver.
    mutable std::mutex inputs_mutex_;
    std::vector<std::vector<InputState>> input_history_;
    // Per input module: first word → indices into its history.
    std::vector<std::unordered_map<std::uint16_t, std::vector<std::size_t>>> input_index_;
    std::uint64_t input_states_ = 0;

    // The checker's own state, under check_mutex_.
    mutable std::mutex check_mutex_;
    Report report_;
    std::vector<Target> targets_;
    // Per output module: the first time the device acknowledged each value.
    std::vector<std::unordered_map<std::uint16_t, Clock::time_point>> applied_;
    std::vector<std::vector<Op>> carried_;  // per client: ops not checkable yet
    std::vector<Applied> carried_commands_;
    std::uint64_t requests_read_ = 0;  // requests of the simulator's log taken so far
    // Per client and input module: the newest state index it was served.
    std::vector<std::vector<std::size_t>> newest_served_;
    std::vector<std::uint64_t> read_histogram_;
    std::vector<std::uint64_t> write_histogram_;
    std::chrono::microseconds max_read_latency_{};
    std::chrono::microseconds max_write_latency_{};
    std::unique_ptr<sim::ControlClient> checker_control_;
    // Communication loss, under check_mutex_.
    std::vector<LossPeriod> periods_;
    std::size_t activated_ = 0;  // periods_[0, activated_) have begun for the targets
    bool period_open_ = false;   // periods_.back() has no end yet
    Clock::time_point covered_until_ = Clock::time_point::min();
    std::vector<std::pair<Clock::time_point, Clock::time_point>> excluded_;  // [r, s + timeout)
    std::deque<std::pair<Clock::time_point, Clock::time_point>> recent_;     // (sent, received)
    std::vector<Op> confirmations_;  // silence()'s first reads, until past the horizon
    std::vector<Expiry> expiries_;
    std::vector<std::uint16_t> module_value_;  // the last command each output module applied
};

}  // namespace ioport::bench
