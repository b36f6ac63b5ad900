#include "daemon/link_scheduler.hpp"

#include <algorithm>

#include "daemon/identity.hpp"

namespace ioport::daemon {
namespace {

using asio::redirect_error;
using asio::use_awaitable;
using gateway::ModuleStatus;
using modbus::Exception;

std::vector<PollEntry> poll_entries(const config::LinkConfig& link) {
    std::vector<PollEntry> entries;
    if (link.protocol == config::Protocol::id2) return {PollEntry{}, PollEntry{}};
    for (const auto& module : link.modules) {
        const bool output = is_output(module.address.type);
        entries.push_back({output, output ? module.refresh : module.poll});
    }
    return entries;
}

LinkSettings link_settings(const config::LinkConfig& link) {
    return {link.device, link.baud, link.timeout, link.retries};
}

std::string duration_text(std::chrono::microseconds duration) {
    return fmt::format("{} ms", duration.count() / 1000);
}

asio::awaitable<Result<Reading>> failed(Error error) {
    co_return Unexpected(std::move(error));
}

// An ID-2 link's entries: the stop input, then the count.
constexpr std::size_t id2_count_entry = 1;

bool is_analog(ModuleType type) {
    return reply_words(type) > 0 && full_scale(type) > 0;
}

// A failed transaction of a write, as the write's result.
WriteResult write_failure(const Error& error) {
    switch (failure_of(error.code)) {
        case Failure::error_ack:
            return WriteResult::error_ack;
        case Failure::no_answer:
        case Failure::bad_answer:
            return WriteResult::no_answer;
        case Failure::port:
        case Failure::cancelled:
            break;
    }
    return WriteResult::link_down;
}

// Of the commands of one request, the outcome that says most: the port gone, then no answer
// (both 0B), then an error ack (04).
WriteResult worse(WriteResult a, WriteResult b) {
    return static_cast<int>(a) > static_cast<int>(b) ? a : b;
}

}  // namespace

std::string_view to_string(WriteResult result) {
    switch (result) {
        case WriteResult::confirmed:
            return "confirmed";
        case WriteResult::error_ack:
            return "error_ack";
        case WriteResult::no_answer:
            return "no_answer";
        case WriteResult::link_down:
            return "link_down";
        case WriteResult::busy:
            return "busy";
        case WriteResult::dropped:
            return "dropped";
    }
    return "unknown";
}

std::optional<Exception> exception_of(WriteResult result) {
    switch (result) {
        case WriteResult::confirmed:
            return std::nullopt;
        case WriteResult::error_ack:
            return Exception::server_device_failure;
        case WriteResult::busy:
            return Exception::server_device_busy;
        case WriteResult::no_answer:
        case WriteResult::link_down:
        case WriteResult::dropped:
            break;
    }
    return Exception::gateway_target_failed;
}

struct LinkScheduler::PendingWrite {
    PendingWrite(const asio::any_io_executor& executor, gateway::WritePlan write_plan)
        : plan(std::move(write_plan)), done(executor, Clock::time_point::max()) {}
    gateway::WritePlan plan;
    asio::steady_timer done;  // cancelled when the outcome is known
    bool finished = false;
    WriteResult outcome = WriteResult::link_down;
};

LinkScheduler::LinkScheduler(const asio::any_io_executor& executor, const config::LinkConfig& link,
                             gateway::WordOrder word_order, Log& log, EventLog& events)
    : config_(link),
      identity_(device_identity(link, IOPORTD_VERSION)),
      word_order_(word_order),
      log_(log),
      events_(events),
      link_(executor, link_settings(link)),
      wake_(executor),
      plan_(poll_entries(link)) {
    state_.kind =
        link.protocol == config::Protocol::id2 ? gateway::UnitKind::id2 : gateway::UnitKind::ioport;
    state_.status.fill(ModuleStatus::not_configured);
    if (state_.kind == gateway::UnitKind::id2) {
        entries_ = {{.target = id2::Command::stop_input, .slot = 0},
                    {.target = id2::Command::count, .slot = 0}};
        state_.status[0] = ModuleStatus::not_polled;
    }
    for (const auto& module : link.modules) {
        entries_.push_back({.target = module.address,
                            .slot = slot(module.address),
                            .desired = module.initial,
                            .initial = module.initial,
                            .safe = module.safe});
        if (is_analog(module.address.type)) entries_.back().trend = std::make_shared<Trend>();
        state_.status[static_cast<std::size_t>(slot(module.address))] = ModuleStatus::not_polled;
    }
    (void)image(true);
}

void LinkScheduler::start() {
    // The first attempt is made at once, so that start-up has tried every port before the
    // Modbus server accepts its first client.
    asio::co_spawn(wake_.get_executor(), run(try_open()), asio::detached);
}

void LinkScheduler::finish(config::OnShutdown outputs, std::function<void()> finished) {
    finishing_ = outputs;
    finished_ = std::move(finished);
    wake_.cancel();  // the loop may be asleep until the next poll or reopen
}

void LinkScheduler::stop() {
    stopping_ = true;
    wake_.cancel();
    link_.close();
    state_.port_open = false;
    fail_pending_writes(WriteResult::link_down);
}

int LinkScheduler::modules_online() const {
    return static_cast<int>(
        std::count(state_.status.begin(), state_.status.end(), ModuleStatus::online));
}

asio::awaitable<void> LinkScheduler::run(bool open) {
    const auto self = shared_from_this();  // a reload may let go of this link while it runs
    auto delay = first_reopen_delay;
    while (!stopping_ && !finishing_) {
        if (open) {
            delay = first_reopen_delay;
            co_await serve_port();
        } else {
            co_await sleep_until(Clock::now() + delay);
            delay = std::min(2 * delay, max_reopen_delay);
        }
        open = !stopping_ && !finishing_ && try_open();
    }
    if (finishing_ == config::OnShutdown::initial && !stopping_) co_await set_outputs_to_initial();
    stop();
    if (auto finished = std::exchange(finished_, nullptr)) finished();
}

bool LinkScheduler::try_open() {
    auto opened = link_.open();
    if (opened) {
        auto text =
            fmt::format("link {}: {} open at {} baud, unit {}{}", config_.name, config_.device,
                        config_.baud, config_.unit_id, link_.low_latency() ? ", low latency" : "");
        log_.info(fields(), "{}", text);
        events_.add(EventKind::port_up, config_.name, {}, {}, std::move(text));
        state_.port_open = true;
        last_open_error_.clear();
        plan_.port_opened(Clock::now());
        return true;
    }
    if (opened.error().message != last_open_error_) {
        // Once per distinct reason: a port that stays away for hours must not flood the log.
        last_open_error_ = opened.error().message;
        log_.warn(fields(), "link {}: {}; retrying every {} at most", config_.name,
                  last_open_error_, duration_text(max_reopen_delay));
    }
    return false;
}

asio::awaitable<void> LinkScheduler::serve_port() {
    while (!stopping_ && link_.is_open()) {
        if (finishing_ && writes_.empty()) co_return;  // writes go first, so they are all done
        if (std::exchange(safe_state_due_, false)) {
            co_await send_safe_state();
            continue;
        }
        const auto step = plan_.next(Clock::now(), !writes_.empty());
        switch (step.kind) {
            case PollPlan::Kind::write: {
                const auto write = writes_.front();
                writes_.pop_front();
                co_await execute(*write);
                break;
            }
            case PollPlan::Kind::refresh:
                co_await refresh(step.entry);
                break;
            case PollPlan::Kind::poll:
                co_await poll(step.entry);
                break;
            case PollPlan::Kind::idle:
                co_await sleep_until(step.wake_at);
                break;
        }
    }
}

asio::awaitable<void> LinkScheduler::sleep_until(Clock::time_point when) {
    wake_.expires_at(when);
    asleep_until_ = when;
    boost::system::error_code ec;  // cancelled: a write arrived, or stop()
    co_await wake_.async_wait(redirect_error(use_awaitable, ec));
    asleep_until_.reset();
    woke_ = Clock::now();
}

asio::awaitable<void> LinkScheduler::set_outputs_to_initial() {
    int set = 0;
    for (std::size_t i = 0; i < entries_.size() && !stopping_; ++i) {
        const auto* module = std::get_if<ModuleAddress>(&entries_[i].target);
        if (module == nullptr || !is_output(module->type)) continue;
        const auto what = to_string(*module);
        if (!link_.is_open()) {
            log_.warn(fields(what), "link {}: {} not set to its initial value: port not open",
                      config_.name, what);
            continue;
        }
        const auto result = co_await transact(i, entries_[i].initial);
        record(i, result);
        if (result) {
            entries_[i].desired = entries_[i].initial;
            confirmed(i, entries_[i].initial);
            ++set;
        } else {
            log_.warn(fields(what), "link {}: {} not set to its initial value: {}", config_.name,
                      what, result.error().message);
        }
    }
    if (set > 0)
        log_.info(fields(), "link {}: {} output module(s) set to their initial values",
                  config_.name, set);
}

LogFields LinkScheduler::fields(std::string_view module) const {
    return {config_.name, config_.unit_id, module, {}};
}

bool LinkScheduler::progressing(Clock::time_point now) const {
    if (asleep_until_ == Clock::time_point::max()) return true;  // nothing to poll, ever
    // Asleep: stuck only if its timer is overdue.
    const auto since = asleep_until_ ? *asleep_until_ : std::max(woke_, link_.last_activity());
    return now < since + link_.longest_wait() + watchdog_slack;
}

// Not a coroutine: it hands back the link's, which saves a coroutine frame per transaction.
asio::awaitable<Result<Reading>> LinkScheduler::transact(std::size_t entry, std::uint16_t value) {
    const auto& target = entries_[entry].target;
    if (const auto* command = std::get_if<id2::Command>(&target))
        return link_.transact(make_exchange(*command));
    auto exchange = make_exchange(std::get<ModuleAddress>(target), value);
    if (!exchange) return failed(std::move(exchange.error()));
    return link_.transact(std::move(*exchange));
}

asio::awaitable<void> LinkScheduler::poll(std::size_t entry) {
    const auto result = co_await transact(entry, 0);
    if (result) {
        auto& polled = entries_[entry];
        if (const auto* command = std::get_if<id2::Command>(&polled.target))
            gateway::store_id2(image_.tables(), *command, result->raw[0]);
        else
            gateway::store_reading(image_.tables(), std::get<ModuleAddress>(polled.target), *result,
                                   word_order_);
        polled.reading = *result;
        if (polled.trend) polled.trend->add(std::chrono::system_clock::now(), result->raw);
    }
    record(entry, result);
}

asio::awaitable<void> LinkScheduler::refresh(std::size_t entry) {
    const auto value = entries_[entry].desired;
    const auto result = co_await transact(entry, value);
    if (result) confirmed(entry, value);
    record(entry, result);
}

void LinkScheduler::confirmed(std::size_t entry, std::uint16_t value) {
    entries_[entry].confirmed = value;
    gateway::store_output(image_.tables(), std::get<ModuleAddress>(entries_[entry].target), value);
    notify(entries_[entry].slot);
}

asio::awaitable<WriteResult> LinkScheduler::write(gateway::WritePlan plan) {
    if (plan.changes.empty() && !plan.reset_counter) co_return WriteResult::confirmed;
    if (!state_.port_open || stopping_ || finishing_) {
        ++writes_count_[static_cast<std::size_t>(WriteResult::link_down)];
        co_return WriteResult::link_down;
    }
    if (writes_.size() >= static_cast<std::size_t>(config_.max_pending_writes)) {
        refuse_busy();
        co_return WriteResult::busy;
    }
    const auto self = shared_from_this();  // a reload may let go of this link meanwhile
    auto pending = std::make_shared<PendingWrite>(wake_.get_executor(), std::move(plan));
    writes_.push_back(pending);
    wake_.cancel();  // the loop may be idle until the next poll is due
    boost::system::error_code ec;
    if (!pending->finished) co_await pending->done.async_wait(redirect_error(use_awaitable, ec));
    ++writes_count_[static_cast<std::size_t>(pending->outcome)];
    co_return pending->outcome;
}

// Counted, and logged at most once a minute with the number refused meanwhile: the writer is a
// flood, and one line per refusal would be another.
void LinkScheduler::refuse_busy() {
    ++writes_count_[static_cast<std::size_t>(WriteResult::busy)];
    const auto held = busy_logged_.admit("", Clock::now());
    if (!held) return;
    log_.warn(fields(),
              "link {}: a write refused (Modbus exception 06, DCMD refused): {} writes are "
              "waiting for the line (max_pending_writes); logged at most once a minute{}",
              config_.name, config_.max_pending_writes, held_back(*held));
}

void LinkScheduler::enter_safe_state() {
    desire_safe_state();  // with the port down, the state restored at reopen
    if (!state_.port_open || stopping_ || finishing_) return;
    if (!writes_.empty())
        log_.warn(fields(), "link {}: {} waiting write(s) dropped for the safe state", config_.name,
                  writes_.size());
    fail_pending_writes(WriteResult::dropped);
    safe_state_due_ = true;
    wake_.cancel();
}

void LinkScheduler::desire_safe_state() {
    for (auto& entry : entries_)
        if (const auto* module = std::get_if<ModuleAddress>(&entry.target);
            module && is_output(module->type))
            entry.desired = entry.safe;
}

// Whether each command is confirmed or not, the safe value is the desired state from now on:
// refresh keeps sending it, and reopen restores it.
asio::awaitable<void> LinkScheduler::send_safe_state() {
    desire_safe_state();
    int sent = 0;
    for (std::size_t i = 0; i < entries_.size() && link_.is_open() && !stopping_; ++i) {
        const auto* module = std::get_if<ModuleAddress>(&entries_[i].target);
        if (module == nullptr || !is_output(module->type)) continue;
        const auto result = co_await transact(i, entries_[i].safe);
        if (result) {
            confirmed(i, entries_[i].safe);
            ++sent;
        }
        record(i, result);
    }
    log_.info(fields(), "link {}: {} output module(s) set to their safe values", config_.name,
              sent);
}

asio::awaitable<void> LinkScheduler::execute(PendingWrite& write) {
    auto outcome = WriteResult::confirmed;
    for (const auto& change : write.plan.changes) {
        if (!link_.is_open()) {
            outcome = WriteResult::link_down;
            break;
        }
        // The others stay applied; the request answers the worst outcome, 0B before 04.
        outcome = worse(outcome, co_await apply(change));
    }
    if (write.plan.reset_counter) outcome = co_await reset_counter();
    write.outcome = outcome;
    write.finished = true;
    write.done.cancel();
}

asio::awaitable<WriteResult> LinkScheduler::apply(const gateway::OutputChange& change) {
    const auto entry = entry_of(change.module);
    if (!entry) co_return WriteResult::error_ack;  // the planner rules this out
    auto& module = entries_[*entry];
    // Merged now, not when the request arrived: another client's write may have come first.
    const auto value = gateway::merged(module.desired, change);
    const auto result = co_await transact(*entry, value);
    if (result) {
        module.desired = value;
        confirmed(*entry, value);
    }
    record(*entry, result);
    co_return result ? WriteResult::confirmed : write_failure(result.error());
}

asio::awaitable<WriteResult> LinkScheduler::reset_counter() {
    if (!link_.is_open()) co_return WriteResult::link_down;
    const auto result = co_await link_.transact(make_exchange(id2::Command::reset));
    // A confirmed reset shows in the image with the next read of the count. A failed one is a
    // failure of the device like any other, and leaves the count in doubt: stale until read.
    if (result) co_return WriteResult::confirmed;
    record(id2_count_entry, result);
    co_return write_failure(result.error());
}

void LinkScheduler::record(std::size_t index, const Result<Reading>& result) {
    const auto now = Clock::now();
    auto& entry = entries_[index];
    if (result) {
        plan_.done(index, true, now);
        entry.status = ModuleStatus::online;
        entry.last_good = now;
        update_slot(entry, nullptr);
        notify(entry.slot);
        return;
    }
    const auto& error = result.error();
    switch (failure_of(error.code)) {
        case Failure::cancelled:
            return;
        case Failure::port:
            port_lost(error);
            return;
        case Failure::no_answer:
            entry.status = ModuleStatus::no_answer;
            break;
        case Failure::bad_answer:
        case Failure::error_ack:
            entry.status = ModuleStatus::bad_answer;
            break;
    }
    plan_.done(index, false, now);
    update_slot(entry, &error);
    notify(entry.slot);
}

void LinkScheduler::update_slot(const Entry& changed, const Error* error) {
    auto status = changed.status;
    auto last_good = changed.last_good;
    if (state_.kind == gateway::UnitKind::id2) {
        // The stop input and the count share slot 0: online only while both reads succeed,
        // failed or not polled yet while either is, as old as the older of the two good reads.
        const auto& other = &changed == &entries_[0] ? entries_[1] : entries_[0];
        if (status == ModuleStatus::online) status = other.status;
        last_good = last_good && other.last_good
                        ? std::optional(std::min(*last_good, *other.last_good))
                        : std::nullopt;
    }
    last_good_[static_cast<std::size_t>(changed.slot)] = last_good;
    set_status(changed.slot, status, error);
}

void LinkScheduler::set_status(int slot_index, ModuleStatus status, const Error* error) {
    auto& current = state_.status[static_cast<std::size_t>(slot_index)];
    if (current == status) return;
    const bool was_online = current == ModuleStatus::online;
    current = status;
    const auto what = state_.kind == gateway::UnitKind::id2 ? std::string("ID-2")
                                                            : to_string(module_at_slot(slot_index));
    if (status == ModuleStatus::online) {
        auto text = fmt::format("link {}: {} online", config_.name, what);
        log_.info(fields(what), "{}", text);
        events_.add(EventKind::module_online, config_.name, what, {}, std::move(text));
    } else if (was_online || error) {
        auto text = fmt::format("link {}: {} offline: {}", config_.name, what,
                                error ? error->message : std::string("port closed"));
        log_.warn(fields(what), "{}", text);
        events_.add(EventKind::module_offline, config_.name, what, {}, std::move(text));
    }
}

void LinkScheduler::port_lost(const Error& error) {
    link_.close();
    if (!state_.port_open) return;
    state_.port_open = false;
    auto text = fmt::format("link {}: port down: {}; reopening", config_.name, error.message);
    log_.warn(fields(), "{}", text);
    events_.add(EventKind::port_down, config_.name, {}, {}, std::move(text));
    // Polled modules answer 0B (or hold) while the port is away; never-polled ones stay 4.
    for (auto& entry : entries_)
        if (entry.status != ModuleStatus::not_polled) entry.status = ModuleStatus::no_answer;
    for (auto& status : state_.status)
        if (status != ModuleStatus::not_configured && status != ModuleStatus::not_polled)
            status = ModuleStatus::no_answer;
    fail_pending_writes(WriteResult::link_down);
    notify(-1);
}

LinkScheduler::Subscription LinkScheduler::subscribe(Observer observer) {
    auto subscription = std::make_shared<const Observer>(std::move(observer));
    observers_.push_back(subscription);
    return subscription;
}

void LinkScheduler::notify(int slot) {
    std::erase_if(observers_, [](const auto& observer) { return observer.expired(); });
    // By index: an observer may subscribe while called; the call holds its own observer alive.
    for (std::size_t i = 0; i < observers_.size(); ++i)
        if (const auto observer = observers_[i].lock()) (*observer)(slot);
}

void LinkScheduler::fail_pending_writes(WriteResult outcome) {
    for (const auto& write : writes_) {
        write->outcome = outcome;
        write->finished = true;
        write->done.cancel();
    }
    writes_.clear();
}

std::optional<std::size_t> LinkScheduler::entry_of(ModuleAddress module) const {
    for (std::size_t i = 0; i < entries_.size(); ++i)
        if (const auto* address = std::get_if<ModuleAddress>(&entries_[i].target);
            address && *address == module)
            return i;
    return std::nullopt;
}

std::vector<ModuleView> LinkScheduler::modules() const {
    std::vector<ModuleView> views;
    if (state_.kind == gateway::UnitKind::id2) {
        views.push_back(*module_at(0));
        return views;
    }
    views.reserve(entries_.size());
    for (const auto& entry : entries_)
        views.push_back(*module_at(entry.slot));
    return views;
}

std::optional<ModuleView> LinkScheduler::module_at(int slot_index) const {
    if (slot_index < 0 || slot_index >= slot_count) return std::nullopt;
    const auto at = static_cast<std::size_t>(slot_index);
    if (state_.kind == gateway::UnitKind::id2) {
        if (slot_index != 0) return std::nullopt;
        const auto& stop = entries_[0].reading;
        const auto& count = entries_[id2_count_entry].reading;
        return ModuleView{.name = "ID-2",
                          .status = state_.status[0],
                          .last_good = last_good_[0],
                          .stop = stop ? std::optional(stop->raw[0] != 0) : std::nullopt,
                          .count = count ? std::optional(count->raw[0]) : std::nullopt};
    }
    const auto entry = entry_of(module_at_slot(slot_index));
    if (!entry) return std::nullopt;
    const auto& e = entries_[*entry];
    return ModuleView{.name = to_string(module_at_slot(slot_index)),
                      .address = module_at_slot(slot_index),
                      .slot = slot_index,
                      .status = state_.status[at],
                      .last_good = last_good_[at],
                      .reading = e.reading,
                      .output = e.confirmed,
                      .trend = e.trend.get()};
}

modbus_mapping_t* LinkScheduler::image(bool diagnostics) {
    if (!diagnostics) return image_.mapping();
    const auto now = Clock::now();
    gateway::Diagnostics d;
    const auto configured = [](ModuleStatus s) { return s != ModuleStatus::not_configured; };
    const bool all_online =
        std::all_of(state_.status.begin(), state_.status.end(),
                    [&](ModuleStatus s) { return !configured(s) || s == ModuleStatus::online; });
    d.link_state = !state_.port_open ? gateway::LinkState::port_not_open
                   : all_online      ? gateway::LinkState::all_online
                                     : gateway::LinkState::some_offline;
    d.last_cycle = plan_.last_cycle();
    d.cycles = plan_.cycles();
    d.transactions_ok = link_.counters().transactions_ok;
    d.transactions_failed = link_.counters().transactions_failed();
    d.opens = link_.counters().opens;
    d.status = state_.status;
    for (std::size_t i = 0; i < slot_count; ++i) {
        const auto& good = last_good_[i];
        d.age_ms[i] =
            good ? static_cast<std::uint32_t>(std::min<long long>(
                       std::chrono::duration_cast<std::chrono::milliseconds>(now - *good).count(),
                       0xFFFFFFFF))
                 : 0xFFFFFFFF;
    }
    gateway::store_diagnostics(image_.tables(), d, word_order_);
    return image_.mapping();
}

}  // namespace ioport::daemon
