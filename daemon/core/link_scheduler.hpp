// One serial link: the port, its polling coroutine, the modules' part of the read model
// (core/model.hpp) and the queue of writes. Everything runs on the one io_context; transports
// read the model and subscribe to its changes, and every write, whichever transport asked for it,
// comes through write(): validated by the transport's planner, queued here, audited here once.
//
// The loop: open the port (retrying at 100 ms doubling to 2 s), restore the outputs, then do
// what the PollPlan says next — the safe state when due, writes, due refreshes, poll reads — one
// transaction at a time. A lost port fails the queued writes (link_down) and goes back to opening.
//
// Owned through a shared_ptr: the loop and a client's write keep it alive, so a reload can drop
// a link while they still finish.
#pragma once

#include <array>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/base/log.hpp"
#include "daemon/core/bus.hpp"
#include "daemon/core/model.hpp"
#include "daemon/core/poll_plan.hpp"
#include "daemon/core/trend.hpp"
#include "link/asio.hpp"
#include "link/serial_link.hpp"
#include "protocol/gateway_map.hpp"

namespace ioport::daemon {

inline constexpr std::chrono::microseconds first_reopen_delay = 100ms;
inline constexpr std::chrono::microseconds max_reopen_delay = 2s;
// What a loaded machine may add to a wait before the loop runs again.
inline constexpr std::chrono::microseconds watchdog_slack = 1s;

class LinkScheduler : public std::enable_shared_from_this<LinkScheduler> {
  public:
    // `bus`: where it tells what happens (core/bus.hpp): values, statuses, its port, writes.
    LinkScheduler(const asio::any_io_executor& executor, const config::LinkConfig& link, Log& log,
                  EventBus& bus);
    LinkScheduler(const LinkScheduler&) = delete;
    LinkScheduler& operator=(const LinkScheduler&) = delete;

    // Tries to open the port once, now, and starts the loop.
    void start();
    // The orderly end: no more polling; the queued writes are done, then with
    // OnShutdown::initial every output is set to its `initial` value, then the port is closed
    // and `finished` called.
    void finish(config::OnShutdown outputs, std::function<void()> finished);
    // The abrupt end: the transaction in flight is abandoned, queued writes answer 0B, the port
    // is closed at once.
    void stop();

    const config::LinkConfig& config() const { return config_; }
    // Where it tells what happens; the gateway's one.
    EventBus& bus() const { return bus_; }
    // A reload that changed only names, units or scales (`next` == config() as settings): the
    // link keeps running, its port open and its outputs as they are; the bus is told.
    void retag(const config::LinkConfig& next);
    // The port and every slot's status, as the Modbus map's planner decides requests by.
    const gateway::UnitState& state() const { return state_; }
    // Sends a validated write and completes when the device acknowledged it or it failed.
    // Counted in writes() when it reached the link: an empty plan is confirmed at once. Refused
    // at once (busy) when max_pending_writes are waiting: a flood of writes, from whichever
    // path, must neither grow without bound nor be applied hours after it was asked for. A write
    // that reached the link is audited once its outcome is known: logged (with the journal's
    // audit fields) and published as WriteAudited, in `origin`'s words.
    asio::awaitable<WriteResult> write(gateway::WritePlan plan, WriteOrigin origin);
    // Communication loss (gateway.md §5.3): every output module's safe value becomes its desired
    // state and is sent next, after the transaction in flight; the writes still waiting are
    // dropped, as the clients that asked for them fell silent. With the port down it is the
    // state restored at reopen.
    void enter_safe_state();

    bool port_open() const { return state_.port_open; }
    int modules_online() const;
    // The read model: the configured modules in configuration order (the ID-2: one).
    const std::vector<ModuleState>& modules() const { return modules_; }
    // The module of `slot` (the ID-2's is 0); null when none is configured there.
    const ModuleState* module_at(int slot) const;
    // Writes by WriteResult: the clients', and the safe state of a communication loss.
    const std::array<std::uint64_t, write_result_count>& writes() const { return writes_count_; }
    const LinkCounters& counters() const { return link_.counters(); }
    // The last complete poll cycle; 0 before the first.
    std::chrono::microseconds last_cycle() const { return plan_.last_cycle(); }
    std::uint64_t cycles() const { return plan_.cycles(); }
    // The loop is not stuck: it is asleep until a poll or reopen is due, or its serial link
    // acted within the longest wait the link ever makes (one timeout) and a second to spare for
    // a busy machine. A whole step may take far longer on a noisy line, and that is not a stall.
    bool progressing(Clock::time_point now) const;

  private:
    struct Entry {
        Target target;  // a module, or an ID-2 command
        int slot;
        std::size_t module = 0;     // its place in modules_
        std::uint16_t desired = 0;  // outputs: last confirmed value, `initial`, or `safe`
        std::uint16_t initial = 0;
        std::uint16_t safe = 0;
        // The outcome of this entry's last transaction: the slot's status for a module, one of
        // the two the ID-2's slot 0 is made of (update_slot).
        gateway::ModuleStatus outcome = gateway::ModuleStatus::not_polled;
        std::optional<Clock::time_point> last_good{};
        std::shared_ptr<Trend> trend{};  // analog modules
    };
    struct PendingWrite;

    asio::awaitable<void> run(bool open);
    bool try_open();
    asio::awaitable<void> serve_port();
    asio::awaitable<Result<Reading>> transact(std::size_t entry, std::uint16_t value);
    asio::awaitable<void> poll(std::size_t entry);
    asio::awaitable<void> refresh(std::size_t entry);
    asio::awaitable<void> execute(PendingWrite& write);
    asio::awaitable<WriteResult> apply(const gateway::OutputChange& change);
    asio::awaitable<WriteResult> reset_counter();
    void confirmed(std::size_t entry, std::uint16_t value);
    void store(std::size_t entry, const Reading& reading);
    // The module's point values, from what it holds now (ModuleState::values).
    void make_values(ModuleState& module);
    asio::awaitable<void> sleep_until(Clock::time_point when);
    asio::awaitable<void> set_outputs_to_initial();
    asio::awaitable<void> send_safe_state();
    void desire_safe_state();
    LogFields fields(std::string_view module = {}) const;

    void record(std::size_t entry, const Result<Reading>& result);
    void update_slot(const Entry& changed, const Error* error);
    void set_status(int slot, gateway::ModuleStatus status, const Error* error);
    void port_lost(const Error& error);
    void audit(const WriteOrigin& origin, WriteResult result);
    void fail_pending_writes(WriteResult outcome);
    void refuse_busy();
    std::optional<std::size_t> entry_of(ModuleAddress module) const;

    config::LinkConfig config_;
    Log& log_;
    EventBus& bus_;
    SerialLink link_;
    asio::steady_timer wake_;
    PollPlan plan_;
    std::vector<Entry> entries_;
    std::deque<std::shared_ptr<PendingWrite>> writes_;  // at most max_pending_writes
    bool safe_state_due_ = false;  // sent before anything else the loop does next
    LogLimiter busy_logged_;       // refusals for a full queue
    std::array<std::uint64_t, write_result_count> writes_count_{};
    gateway::UnitState state_;
    std::vector<ModuleState> modules_;
    std::array<int, slot_count> module_of_slot_{};  // index into modules_, -1: none
    bool stopping_ = false;
    std::optional<config::OnShutdown> finishing_;
    std::function<void()> finished_;
    std::string last_open_error_;
    Clock::time_point woke_ = Clock::now();  // started, or last woke from a sleep
    std::optional<Clock::time_point> asleep_until_;
};

// The running links, in configuration order.
using Links = std::vector<std::shared_ptr<LinkScheduler>>;

// For the outputs that publish modules as they change (Sparkplug, plain MQTT): a subscription to
// the bus that calls changed(link, slot) when a module of one of `links` changes its values or
// status (slot -1: every module of the link, its port opened or lost). A write's values come as
// a change of their own; new names and units reach the output through the reload.
EventBus::Subscription watch_module_data(
    EventBus& bus, const Links& links,
    const std::function<void(const LinkScheduler* link, int slot)>& changed);

// /healthz (gateway.md §5.4): every link's port open and every module online.
struct Health {
    bool ok = true;
    std::string reason;  // "link hub0: port not open; link hub1: dim16 2 no answer"
};
Health health(const Links& links);
// One link's part of it: "" while its port is open and every module online, else the reasons
// ("link hub0: dim16 2 no answer").
std::string link_problems(const LinkScheduler& link);

}  // namespace ioport::daemon
