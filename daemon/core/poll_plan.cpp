#include "daemon/core/poll_plan.hpp"

#include <algorithm>

namespace ioport::daemon {

std::chrono::microseconds backoff(int consecutive_failures) {
    if (consecutive_failures <= 0) return {};
    auto delay = first_backoff;
    for (int i = 1; i < consecutive_failures && delay < max_backoff; ++i)
        delay *= 2;
    return std::min(delay, max_backoff);
}

PollPlan::PollPlan(const std::vector<PollEntry>& entries) {
    entries_.reserve(entries.size());
    for (const auto& entry : entries) {
        if (entry.output) outputs_.push_back(entries_.size());
        entries_.push_back(State{entry, {}, 0});
    }
}

void PollPlan::port_opened(Clock::time_point now) {
    for (auto& state : entries_) {
        state.due = now;
        state.failures = 0;
    }
    cursor_ = 0;
    pass_did_work_ = false;
}

std::optional<std::size_t> PollPlan::due_refresh(Clock::time_point now) const {
    std::optional<std::size_t> earliest;
    for (const auto i : outputs_) {
        const auto& state = entries_[i];
        if (state.due <= now && (!earliest || state.due < entries_[*earliest].due)) earliest = i;
    }
    return earliest;
}

bool PollPlan::anything_due(Clock::time_point now) const {
    return std::any_of(entries_.begin(), entries_.end(),
                       [&](const State& state) { return state.due <= now; });
}

PollPlan::Step PollPlan::next(Clock::time_point now, bool write_pending) {
    // Writes go first, but never twice in a row while a refresh or poll read waits: a stream of
    // writes to a dead module, each costing its retries and a silence, must not starve polling.
    const bool take_turn = !after_write_ || !anything_due(now);
    after_write_ = write_pending && take_turn;
    if (after_write_) return {Kind::write};
    const auto refresh = due_refresh(now);
    const auto poll = due_poll(now);
    // Between writes, the turns alternate between refreshes and poll reads when both wait:
    // with every output refreshing (one of them dead) they would otherwise take every turn.
    const bool poll_first = write_pending && poll_owed_ && poll;
    if (refresh && !poll_first) {
        poll_owed_ = write_pending && poll;
        return {Kind::refresh, *refresh};
    }
    if (poll) {
        poll_owed_ = false;
        return {Kind::poll, cursor_++};
    }
    auto wake = Clock::time_point::max();
    for (const auto& state : entries_)
        wake = std::min(wake, state.due);
    return {Kind::idle, 0, wake};
}

std::optional<std::size_t> PollPlan::due_poll(Clock::time_point now) {
    // One look at every entry, wrapping at most once: the round-robin resumes where it stopped,
    // and stops at the entry that is due, which next() takes or leaves for the next turn.
    for (std::size_t looked = 0; looked <= entries_.size() && !entries_.empty(); ++looked) {
        if (cursor_ == entries_.size()) {
            cursor_ = 0;
            finish_pass(now);
        }
        const auto& state = entries_[cursor_];
        if (!state.entry.output && state.due <= now) return cursor_;
        ++cursor_;
    }
    return std::nullopt;
}

void PollPlan::done(std::size_t entry, bool ok, Clock::time_point now) {
    auto& state = entries_.at(entry);
    pass_did_work_ = true;
    state.failures = ok ? 0 : state.failures + 1;
    state.due = now + std::max(state.entry.interval, backoff(state.failures));
}

void PollPlan::finish_pass(Clock::time_point now) {
    // A pass in which nothing was due is not a cycle: the link was idle, not polling.
    if (!pass_did_work_) return;
    pass_did_work_ = false;
    ++cycles_;
    if (last_completion_)
        last_cycle_ =
            std::chrono::duration_cast<std::chrono::microseconds>(now - *last_completion_);
    last_completion_ = now;
}

}  // namespace ioport::daemon
