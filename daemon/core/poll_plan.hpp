// What a link does next, as a pure function of its modules' due times: the order of work of
// gateway.md §4 (client writes, then refreshes that are due, then poll reads in round-robin; but
// after a write, a refresh or poll read that is due goes before the next write, and those turns
// between writes alternate between refreshes and poll reads while both wait),
// the back-off of modules that keep failing, and the poll cycle's bookkeeping. The link's
// coroutine (link_scheduler) asks `next`, does the transaction and reports it with `done`.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

namespace ioport::daemon {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

// A module that failed is next tried after 250 ms, then 500 ms, 1 s, 2 s and at most 4 s, so a
// dead module (each try costs (retries + 1) timeouts and a silence) takes a small, bounded share
// of the line and is still found again within seconds when it comes back.
inline constexpr std::chrono::microseconds first_backoff = 250ms;
inline constexpr std::chrono::microseconds max_backoff = 4s;
std::chrono::microseconds backoff(int consecutive_failures);

struct PollEntry {
    bool output = false;  // refreshed with its desired state; inputs are read
    // Inputs: at most this often (0 = every cycle). Outputs: re-send the state this often.
    std::chrono::microseconds interval{0};
};

class PollPlan {
  public:
    enum class Kind { write, refresh, poll, idle };
    struct Step {
        Kind kind;
        std::size_t entry = 0;        // refresh, poll: index into the entries
        Clock::time_point wake_at{};  // idle: when something is due next
    };

    explicit PollPlan(const std::vector<PollEntry>& entries);

    // The port was (re)opened: every module is due now, outputs first, and back-offs restart.
    void port_opened(Clock::time_point now);
    Step next(Clock::time_point now, bool write_pending);
    // A transaction of `entry` ended (poll, refresh, or a client write to an output module, which
    // also counts as its refresh).
    void done(std::size_t entry, bool ok, Clock::time_point now);

    std::uint64_t cycles() const { return cycles_; }
    // Time between the last two cycle completions; zero until two have completed.
    std::chrono::microseconds last_cycle() const { return last_cycle_; }

  private:
    struct State {
        PollEntry entry;
        Clock::time_point due{};
        int failures = 0;
    };
    std::optional<std::size_t> due_refresh(Clock::time_point now) const;
    // The next input due in the round-robin; the cursor stays on it.
    std::optional<std::size_t> due_poll(Clock::time_point now);
    bool anything_due(Clock::time_point now) const;
    void finish_pass(Clock::time_point now);

    std::vector<State> entries_;
    // The output entries: every step looks for a due refresh, and most entries are inputs.
    std::vector<std::size_t> outputs_;
    std::size_t cursor_ = 0;
    bool after_write_ = false;  // the last step was a write
    bool poll_owed_ = false;  // the last turn between writes went to a refresh while a poll waited
    bool pass_did_work_ = false;
    std::optional<Clock::time_point> last_completion_;
    std::chrono::microseconds last_cycle_{};
    std::uint64_t cycles_ = 0;
};

}  // namespace ioport::daemon
