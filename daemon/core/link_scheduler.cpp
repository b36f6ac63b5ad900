#include "daemon/core/link_scheduler.hpp"

#include <algorithm>

namespace ioport::daemon {
namespace {

using asio::redirect_error;
using asio::use_awaitable;
using gateway::ModuleStatus;

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

struct LinkScheduler::PendingWrite {
    PendingWrite(const asio::any_io_executor& executor, gateway::WritePlan write_plan)
        : plan(std::move(write_plan)), done(executor, Clock::time_point::max()) {}
    gateway::WritePlan plan;
    asio::steady_timer done;  // cancelled when the outcome is known
    bool finished = false;
    WriteResult outcome = WriteResult::link_down;
};

LinkScheduler::LinkScheduler(const asio::any_io_executor& executor, const config::LinkConfig& link,
                             Log& log, EventBus& bus)
    : config_(link),
      log_(log),
      bus_(bus),
      link_(executor, link_settings(link)),
      wake_(executor),
      plan_(poll_entries(link)) {
    state_.kind =
        link.protocol == config::Protocol::id2 ? gateway::UnitKind::id2 : gateway::UnitKind::ioport;
    state_.status.fill(ModuleStatus::not_configured);
    module_of_slot_.fill(-1);
    if (state_.kind == gateway::UnitKind::id2) {
        entries_ = {{.target = id2::Command::stop_input, .slot = 0},
                    {.target = id2::Command::count, .slot = 0}};
        state_.status[0] = ModuleStatus::not_polled;
        modules_.push_back({.name = "ID-2", .unit = &state_});
        module_of_slot_[0] = 0;
    }
    for (auto& module : config_.modules) {
        // A configuration made in code rather than loaded has no tags resolved yet.
        if (module.tags.name.empty()) module.tags = gateway::default_tags(module.address);
        const int at = slot(module.address);
        entries_.push_back({.target = module.address,
                            .slot = at,
                            .module = modules_.size(),
                            .desired = module.initial,
                            .initial = module.initial,
                            .safe = module.safe});
        if (is_analog(module.address.type)) entries_.back().trend = std::make_shared<Trend>();
        module_of_slot_[static_cast<std::size_t>(at)] = static_cast<int>(modules_.size());
        modules_.push_back({.name = to_string(module.address),
                            .address = module.address,
                            .slot = at,
                            .unit = &state_,
                            .trend = entries_.back().trend.get(),
                            .tags = &module.tags});
        state_.status[static_cast<std::size_t>(at)] = ModuleStatus::not_polled;
    }
    for (auto& module : modules_)
        make_values(module);
}

void LinkScheduler::make_values(ModuleState& module) {
    gateway::point_values(module.address ? std::optional(module.address->type) : std::nullopt,
                          {module.reading, module.output, module.stop, module.count}, *module.tags,
                          module.values);
}

void LinkScheduler::retag(const config::LinkConfig& next) {
    // config_.modules is never resized, so the modules' tag pointers stay where they are.
    for (std::size_t i = 0; i < config_.modules.size(); ++i)
        config_.modules[i].tags = next.modules[i].tags;
    for (auto& module : modules_)
        make_values(module);  // rescaled
    bus_.publish(TagsChanged{this});
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
        state_.port_open = true;
        last_open_error_.clear();
        plan_.port_opened(Clock::now());
        bus_.publish(PortChanged{this, true, text});
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
    if (result) store(entry, *result);
    record(entry, result);
}

void LinkScheduler::store(std::size_t index, const Reading& reading) {
    const auto& entry = entries_[index];
    auto& module = modules_[entry.module];
    if (const auto* command = std::get_if<id2::Command>(&entry.target)) {
        if (*command == id2::Command::stop_input)
            module.stop = reading.raw[0] != 0;
        else
            module.count = reading.raw[0];
    } else {
        module.reading = reading;
    }
    make_values(module);
    if (entry.trend) entry.trend->add(std::chrono::system_clock::now(), reading.raw);
    bus_.publish(ValuesChanged{this, &module});
}

asio::awaitable<void> LinkScheduler::refresh(std::size_t entry) {
    const auto value = entries_[entry].desired;
    const auto result = co_await transact(entry, value);
    if (result) confirmed(entry, value);
    record(entry, result);
}

void LinkScheduler::confirmed(std::size_t entry, std::uint16_t value) {
    auto& module = modules_[entries_[entry].module];
    module.output = value;
    make_values(module);
    bus_.publish(ValuesChanged{this, &module});
}

asio::awaitable<WriteResult> LinkScheduler::write(gateway::WritePlan plan, WriteOrigin origin) {
    if (plan.changes.empty() && !plan.reset_counter) co_return WriteResult::confirmed;
    if (!state_.port_open || stopping_ || finishing_) {
        ++writes_count_[static_cast<std::size_t>(WriteResult::link_down)];
        audit(origin, WriteResult::link_down);
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
    audit(origin, pending->outcome);
    co_return pending->outcome;
}

// The one audit record of a write, whichever transport asked for it. A refusal for a full queue
// is not audited one by one: refuse_busy() logs them as the flood they are.
void LinkScheduler::audit(const WriteOrigin& origin, WriteResult result) {
    const WriteAudit audit{.function = origin.function,
                           .address = origin.address,
                           .value = origin.value,
                           .result = to_string(result),
                           .latency_us = std::chrono::duration_cast<std::chrono::microseconds>(
                                             Clock::now() - origin.asked)
                                             .count()};
    auto text = fmt::format("write by {} to unit {} ({}): {}: {} in {} ms", origin.client,
                            config_.unit_id, config_.name, origin.request, audit.result,
                            static_cast<double>(audit.latency_us) / 1000);
    log_.notice(
        {.link = config_.name, .unit = config_.unit_id, .client = origin.client, .audit = &audit},
        "{}", text);
    bus_.publish(WriteAudited{this, &origin, result, text});
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
        // A write like a client's, on the gateway's own behalf: audited and counted as one.
        const auto name = to_string(*module);
        const auto value = fmt::format("0x{:04X}", entries_[i].safe);
        const WriteOrigin origin{.client = "communication loss",
                                 .function = "safe",
                                 .address = name,
                                 .value = value,
                                 .request = fmt::format("safe value {} to {}", value, name)};
        const auto result = co_await transact(i, entries_[i].safe);
        if (result) {
            confirmed(i, entries_[i].safe);
            ++sent;
        }
        record(i, result);
        const auto outcome = result ? WriteResult::confirmed : write_failure(result.error());
        ++writes_count_[static_cast<std::size_t>(outcome)];
        audit(origin, outcome);
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
    // A confirmed reset shows in the model with the next read of the count. A failed one is a
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
        entry.outcome = ModuleStatus::online;
        entry.last_good = now;
        update_slot(entry, nullptr);
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
            entry.outcome = ModuleStatus::no_answer;
            break;
        case Failure::bad_answer:
        case Failure::error_ack:
            entry.outcome = ModuleStatus::bad_answer;
            break;
    }
    plan_.done(index, false, now);
    update_slot(entry, &error);
}

void LinkScheduler::update_slot(const Entry& changed, const Error* error) {
    auto status = changed.outcome;
    auto last_good = changed.last_good;
    if (state_.kind == gateway::UnitKind::id2) {
        // The stop input and the count share slot 0: online only while both reads succeed,
        // failed or not polled yet while either is, as old as the older of the two good reads.
        const auto& other = &changed == &entries_[0] ? entries_[1] : entries_[0];
        if (status == ModuleStatus::online) status = other.outcome;
        last_good = last_good && other.last_good
                        ? std::optional(std::min(*last_good, *other.last_good))
                        : std::nullopt;
    }
    modules_[changed.module].last_good = last_good;
    set_status(changed.slot, status, error);
}

void LinkScheduler::set_status(int slot_index, ModuleStatus status, const Error* error) {
    auto& current = state_.status[static_cast<std::size_t>(slot_index)];
    if (current == status) return;
    const auto before = std::exchange(current, status);
    const bool was_online = before == ModuleStatus::online;
    const auto& module =
        modules_[static_cast<std::size_t>(module_of_slot_[static_cast<std::size_t>(slot_index)])];
    std::string text;
    if (status == ModuleStatus::online) {
        text = fmt::format("link {}: {} online", config_.name, module.name);
        log_.info(fields(module.name), "{}", text);
    } else if (was_online || error) {
        text = fmt::format("link {}: {} offline: {}", config_.name, module.name,
                           error ? error->message : std::string("port closed"));
        log_.warn(fields(module.name), "{}", text);
    }
    bus_.publish(StatusChanged{this, &module, before, status, text});
}

void LinkScheduler::port_lost(const Error& error) {
    link_.close();
    if (!state_.port_open) return;
    state_.port_open = false;
    auto text = fmt::format("link {}: port down: {}; reopening", config_.name, error.message);
    log_.warn(fields(), "{}", text);
    // Polled modules answer 0B (or hold) while the port is away; never-polled ones stay 4.
    for (auto& entry : entries_)
        if (entry.outcome != ModuleStatus::not_polled) entry.outcome = ModuleStatus::no_answer;
    for (const auto& module : modules_)
        if (module.status() != ModuleStatus::not_polled)
            state_.status[static_cast<std::size_t>(module.slot)] = ModuleStatus::no_answer;
    fail_pending_writes(WriteResult::link_down);
    bus_.publish(PortChanged{this, false, text});
}

EventBus::Subscription watch_module_data(
    EventBus& bus, const Links& links,
    const std::function<void(const LinkScheduler* link, int slot)>& changed) {
    std::vector<const LinkScheduler*> watched;
    for (const auto& link : links)
        watched.push_back(link.get());
    auto subscription = bus.subscribe([changed, watched](const BusEvent& event) {
        const auto* link = link_of(event);
        if (link == nullptr || std::ranges::find(watched, link) == watched.end()) return;
        std::visit(
            [&](const auto& e) {
                using E = std::decay_t<decltype(e)>;
                if constexpr (std::is_same_v<E, ValuesChanged> || std::is_same_v<E, StatusChanged>)
                    changed(link, e.module->slot);
                else if constexpr (std::is_same_v<E, PortChanged>)
                    changed(link, -1);
            },
            event);
    });
    return subscription;
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

const ModuleState* LinkScheduler::module_at(int slot_index) const {
    if (slot_index < 0 || slot_index >= slot_count) return nullptr;
    const int index = module_of_slot_[static_cast<std::size_t>(slot_index)];
    return index < 0 ? nullptr : &modules_[static_cast<std::size_t>(index)];
}

std::string link_problems(const LinkScheduler& link) {
    const auto& name = link.config().name;
    if (!link.port_open())
        return fmt::format("link {}: port {} not open", name, link.config().device);
    std::string problems;
    for (const auto& module : link.modules())
        if (module.status() != ModuleStatus::online)
            problems += fmt::format("{}link {}: {} {}", problems.empty() ? "" : "; ", name,
                                    module.name, status_text(module.status()));
    return problems;
}

Health health(const Links& links) {
    Health health;
    for (const auto& link : links) {
        const auto problems = link_problems(*link);
        if (problems.empty()) continue;
        health.ok = false;
        if (!health.reason.empty()) health.reason += "; ";
        health.reason += problems;
    }
    return health;
}

}  // namespace ioport::daemon
