#include "bench/workload.hpp"

#include <sys/select.h>
#include <algorithm>

#include <cerrno>
#include <cstring>
#include <limits>
#include <random>
#include <sstream>

#include <fmt/format.h>
#include <modbus/modbus.h>

namespace ioport::bench {

// --- The hub ------------------------------------------------------------------------------

namespace {

struct ModuleInfo {
    ModuleAddress address;
    bool output;
    int words;  // registers of its data: 3 for acm3p, else 1
    std::uint16_t initial;
    std::uint16_t safe;  // outputs: after a communication loss; never `initial`
};

// Indices into this table name modules below. Inputs first.
constexpr int input_module_count = 5;
const std::array<ModuleInfo, 11> modules{{
    {{ModuleType::dim16, 0}, false, 1, 0, 0},
    {{ModuleType::dim16, 1}, false, 1, 0, 0},
    {{ModuleType::lim16, 0}, false, 1, 0, 0},
    {{ModuleType::acm3p, 0}, false, 3, 0, 0},
    {{ModuleType::dccim, 0}, false, 1, 0, 0},
    // The safe words of dom16 0, 2 and 3 are never written by a client (see run_client): the
    // device applying one is the gateway's safe state, nothing else.
    {{ModuleType::dom16, 0}, true, 1, 0x00F0, 0xA50F},
    {{ModuleType::dom16, 1}, true, 1, 0, 0x8421},
    {{ModuleType::dom16, 2}, true, 1, 0, 0x5AA5},
    {{ModuleType::dom16, 3}, true, 1, 0, 0xC3C3},
    {{ModuleType::rgbdm, 0}, true, 1, 2, 1},  // green; red when safe
    {{ModuleType::mux8m, 0}, true, 1, 0x0707, 0x0000},
}};
// The modules whose every written word is new (run_client's next_word): a command carrying one
// is that write's own.
bool unique_words(int module) {
    return module == 5 || module == 7 || module == 8;
}
// The modules whose safe word only the gateway sends.
bool safe_word_unique(int module) {
    return module == 5 || module == 7 || module == 8;
}
// A word a client must not write to `module`: its initial or safe value.
bool reserved_word(int module, std::uint16_t value) {
    const auto& info = modules[static_cast<std::size_t>(module)];
    return value == info.initial || value == info.safe;
}

std::string sim_name(ModuleAddress address) {
    return fmt::format("{}:{}", name(address.type), address.number);
}

std::optional<int> module_index(ModuleAddress address) {
    for (std::size_t i = 0; i < modules.size(); ++i)
        if (modules[i].address == address) return static_cast<int>(i);
    return std::nullopt;
}

// --- Reads ----------------------------------------------------------------------------------

enum class Table { coils, discrete_inputs, holding_registers, input_registers };

struct ReadKind {
    Table table;
    int address;
    int count;
    std::vector<int> samples;  // the modules it reads, in address order; none: diagnostics
};

const std::vector<ReadKind> read_kinds{
    {Table::input_registers, 0, 2, {0, 1}},          // two dim16 words
    {Table::discrete_inputs, 0, 16, {0}},            // dim16 0 bit by bit
    {Table::input_registers, 8, 1, {2}},             // lim16 0
    {Table::input_registers, 16, 3, {3}},            // acm3p 0, three channels
    {Table::input_registers, 64, 1, {4}},            // dccim 0
    {Table::holding_registers, 0, 4, {5, 6, 7, 8}},  // four dom16 words
    {Table::coils, 16, 16, {6}},                     // dom16 1 bit by bit
    {Table::holding_registers, 8, 1, {9}},           // rgbdm 0
    {Table::holding_registers, 16, 1, {10}},         // mux8m 0
    // Diagnostics, the traffic registers and 1020 (communication loss) included: must always
    // answer. Last: silence() reads it too.
    {Table::input_registers, 1000, 21, {}},
};
const int diagnostics_kind = static_cast<int>(read_kinds.size()) - 1;
constexpr int loss_register = 1020;

// --- Writes ---------------------------------------------------------------------------------

// A write job: one owner writes these targets (module, bits) together.
struct Job {
    std::vector<int> targets;
};
// Targets: 0 dom16 0 word; 1–16 dom16 1 bit 0–15; 17, 18 dom16 2 and 3 words (one FC16);
// 19 rgbdm 0; 20 mux8m 0.
struct TargetInfo {
    int module;
    std::uint16_t mask;
};
std::vector<TargetInfo> target_infos() {
    std::vector<TargetInfo> targets{{5, 0xFFFF}};
    for (int bit = 0; bit < 16; ++bit)
        targets.push_back({6, static_cast<std::uint16_t>(1U << bit)});
    targets.push_back({7, 0xFFFF});
    targets.push_back({8, 0xFFFF});
    targets.push_back({9, 0xFFFF});
    targets.push_back({10, 0xFFFF});
    return targets;
}
std::vector<Job> jobs() {
    std::vector<Job> list{{{0}}};
    for (int bit = 0; bit < 16; ++bit)
        list.push_back({{1 + bit}});
    list.push_back({{17, 18}});
    list.push_back({{19}});
    list.push_back({{20}});
    return list;
}
const std::vector<TargetInfo> all_targets = target_infos();
const std::vector<Job> all_jobs = jobs();

constexpr auto no_request = std::numeric_limits<Clock::rep>::max();
constexpr std::size_t max_problems = 40;
constexpr std::uint64_t problems_per_kind = 8;
constexpr auto histogram_bin = 100us;
constexpr std::size_t histogram_bins = 20000;  // 2 s; slower ones count in the last bin

std::size_t bin_of(std::chrono::microseconds latency) {
    return std::min<std::size_t>(static_cast<std::size_t>(latency / histogram_bin),
                                 histogram_bins - 1);
}

Latency latency_of(const std::vector<std::uint64_t>& histogram, std::chrono::microseconds max) {
    Latency latency;
    latency.max = max;
    for (const auto count : histogram)
        latency.count += count;
    std::uint64_t seen = 0;
    for (std::size_t i = 0; i < histogram.size(); ++i) {
        seen += histogram[i];
        if (seen * 100 >= latency.count * 99) {
            latency.p99 = histogram_bin * static_cast<int>(i + 1);
            break;
        }
    }
    return latency;
}

// The value an input module is given in its n-th state: unique per module (3 tag bits), and
// the three acm3p channels tied together so that a mix of two answers is caught.
std::array<std::uint16_t, 3> input_state(int module, std::uint32_t n) {
    const auto first = static_cast<std::uint16_t>((module + 1) << 13 | (n & 0x1FFF));
    return {first, static_cast<std::uint16_t>(n * 7 + 1), static_cast<std::uint16_t>(~first)};
}

double ms_since(Clock::time_point start, Clock::time_point at) {
    return std::chrono::duration<double, std::milli>(at - start).count();
}

}  // namespace

std::string hub_sim_modules() {
    // Appended piece by piece: `"," + name` is operator+(const char*, std::string&&), which
    // inserts at the front of the temporary, and GCC 12 at -O3 sees an overlapping memcpy there
    // that cannot happen (-Werror=restrict, GCC bug 105329).
    std::string list;
    for (const auto& module : modules) {
        if (!list.empty()) list += ',';
        list += sim_name(module.address);
    }
    return list;
}

std::string hub_link_yaml(const std::string& device, std::chrono::milliseconds timeout, int retries,
                          std::chrono::milliseconds refresh) {
    std::string text = fmt::format(
        "  - name: hub0\n    protocol: ioport\n    device: {}\n    unit_id: 1\n    timeout: {}ms\n"
        "    retries: {}\n    modules:\n",
        device, timeout.count(), retries);
    for (const auto& module : modules) {
        std::string extra;
        if (module.output)
            extra = fmt::format(", initial: 0x{:04X}, safe: 0x{:04X}, refresh: {}ms",
                                module.initial, module.safe, refresh.count());
        else if (module.address.type == ModuleType::dccim)
            extra = ", poll: 100ms";  // a module that is not read every cycle
        text += fmt::format("      - {{ type: {}, number: {}{} }}\n", name(module.address.type),
                            module.address.number, extra);
    }
    return text;
}

bool Report::clean() const {
    return wrong_values == 0 && lost_writes == 0 && failed_writes_pushed == 0 &&
           unanswered_writes == 0 && transport_errors == 0 && unexpected_exceptions == 0;
}

std::string Report::summary() const {
    std::string text = fmt::format(
        "reads {} (ok {}, 0B {}), writes {} (acknowledged {}, 04 {}, 0B {}), serial "
        "transactions {}, commands applied {}, input states {}\n"
        "wrong values {}, lost writes {}, failed writes pushed later {}, unanswered writes {}, "
        "transport errors {}, unexpected exceptions {}; failed writes the device applied late "
        "{}\n"
        "read latency max {:.1f} ms p99 {:.1f} ms; write latency max {:.1f} ms p99 {:.1f} ms\n",
        reads, reads_ok, reads_stale, writes, writes_acked, writes_04, writes_0b, transactions,
        commands_applied, input_states, wrong_values, lost_writes, failed_writes_pushed,
        unanswered_writes, transport_errors, unexpected_exceptions, failed_writes_applied_late,
        static_cast<double>(read_latency.max.count()) / 1000.0,
        static_cast<double>(read_latency.p99.count()) / 1000.0,
        static_cast<double>(write_latency.max.count()) / 1000.0,
        static_cast<double>(write_latency.p99.count()) / 1000.0);
    if (silences > 0 || possible_losses > 0)
        text += fmt::format(
            "comm-loss silences {} (first request after read 1020 = 1: {}, the next 0: {}), "
            "writes in flight at them {}, safe values seen at the device {}, possible comm "
            "losses {}\n",
            silences, silences_signalled, silences_cleared, writes_in_flight_at_silence,
            safe_pushes, possible_losses);
    for (const auto& problem : problems)
        text += "  " + problem + "\n";
    return text;
}

Result<SimClock> sim_clock(const std::string& control) {
    sim::ControlClient client;
    if (auto connected = client.connect(control); !connected) return Unexpected(connected.error());
    const auto reply = client.command("clock");
    if (!reply) return Unexpected(reply.error());
    std::istringstream words(*reply);
    std::int64_t start = 0;
    if (!(words >> start)) return fail(Errc::malformed, "clock: " + *reply);
    return SimClock(Clock::time_point(std::chrono::microseconds(start)));
}

// --- State ----------------------------------------------------------------------------------

struct Workload::Op {
    Clock::time_point sent;
    Clock::time_point received;
    int outcome = 0;  // 0 normal response, 1–255 exception code, < 0 −errno (no response)
    bool write = false;
    int kind = 0;  // read kind or write job
    // Reads: the words per sample in order (acm3p: three). Writes: per target of the job, the
    // value written under the target's mask.
    std::array<std::uint16_t, 4> words{};
    int loss_register = -1;  // diagnostics reads: what 1020 read
    int after_silence = 0;   // silence()'s reads: 1 the first request after it, 2 the second
    // The first request after a silence: the last request before it was sent then, and the last
    // answer to one came then.
    Clock::time_point quiet_from{};
    Clock::time_point drained{};
};

struct Workload::ClientSlot {
    std::atomic<Clock::rep> in_flight{no_request};
    std::atomic<Clock::rep> last_sent{0};
    std::atomic<Clock::rep> last_received{0};
    std::mutex mutex;
    std::vector<Op> done;
};

struct Window {
    Clock::time_point sent;
    Clock::time_point received;
    std::uint16_t value;
    enum class Outcome { acknowledged, failed, unknown } outcome;
    bool spans_modules;
    bool timed_out;  // answered 0B: its attempts may still be read (LateTransmissions)
    int seen = 0;    // commands carrying `value` applied inside the window
    // Of those, how many may have been late transmissions of the owner's earlier failed writes
    // of the same value instead (LateTransmissions): those were sent before this write.
    int maybe_late = 0;
    Clock::time_point last_seen{};
    std::uint64_t last_seen_request = 0;  // its place in the device's log, and its whole word
    std::uint16_t last_seen_word = 0;
    // Acknowledged, sent before a comm loss, and not yet applied when the safe push began: its
    // value must never reach the device now.
    bool after_safe = false;
    bool overwritten = false;  // reported
};

// A write answered 0B after its timeouts whose own transmissions the device may still apply
// after the answer: the simulator reads the line when it gets the CPU, so a command the gateway
// gave up on can reach the device seconds later, after the answer, after the owner's next write
// was sent, together with everything the gateway sent meanwhile. Those are the write's own
// attempts, not desired state, and the line is one queue, so they are told by order alone: at
// most `retries + 1` of them; the attempts of one transaction go out one after the other, so
// once the device has read one of them and then any other request, the rest of what it reads
// was sent after the gateway gave up; and a write sent after the answer (its word unique, see
// fence()) was sent after them too. How late the device read them says nothing: a wall-clock
// grace here once took a starved simulator's reading of words sent in order for lost and pushed
// writes (issue 47). Several failed writes of one owner may wait at once (a device stopped for
// seconds reads the attempts of all of them after their answers): they are kept in the order of
// their answers, which is the order of their attempts on the line, and the device reading an
// attempt of one means every earlier one's attempts are over.
struct LateTransmissions {
    std::uint16_t value;
    int remaining;
    Clock::time_point answered;         // the failed write's answer
    std::optional<std::uint16_t> word;  // the whole word of the one last read, once one was
};

struct Workload::Target {
    TargetInfo info{};
    std::deque<Window> windows;
    std::vector<std::uint16_t> allowed;  // outside the windows: what commands may carry
    std::unordered_set<std::uint16_t> confirmable;
    std::optional<std::uint16_t> last_failed;
    std::deque<LateTransmissions> late;  // oldest first
    // Communication loss: the safe bits (comm loss on), and whether they may be sent since the
    // possible loss `period` began (until a write sent after it ended is acknowledged).
    std::optional<std::uint16_t> safe;
    bool safe_possible = false;
    std::size_t period = 0;
    Clock::time_point safe_seen_at = Clock::time_point::min();  // last command carrying them
    // The desired state became safe then (the push began, or a confirmed loss had time to).
    Clock::time_point expired_at = Clock::time_point::min();
    Clock::time_point settled_sent = Clock::time_point::min();  // last acknowledged write's sent
};

namespace {

// A write sent this long before a silence began reached the gateway before the gateway could
// declare the loss (it reads a request as soon as it runs; both wait for the same thread).
std::chrono::microseconds arrival_bound(std::chrono::milliseconds timeout) {
    return timeout / 2;
}
constexpr auto loss_requests_kept = 10s;

}  // namespace

Workload::Workload(WorkloadSettings settings) : settings_(std::move(settings)) {
    for (int i = 0; i <= settings_.clients; ++i)  // the last: silence()'s reads
        slots_.push_back(std::make_unique<ClientSlot>());
    carried_.resize(slots_.size());
    newest_served_.assign(slots_.size(), std::vector<std::size_t>(input_module_count, 0));
    applied_.resize(modules.size());
    module_value_.assign(modules.size(), 0);  // the power-on state
    input_history_.resize(input_module_count);
    input_index_.resize(input_module_count);
    for (int m = 0; m < input_module_count; ++m) {
        // The power-on state, had from the start.
        input_history_[static_cast<std::size_t>(m)].push_back({{}, {}, {0, 0, 0}});
        input_index_[static_cast<std::size_t>(m)][0].push_back(0);
    }
    for (const auto& info : all_targets) {
        const auto& module = modules[static_cast<std::size_t>(info.module)];
        const auto initial = static_cast<std::uint16_t>(module.initial & info.mask);
        Target target;
        target.info = info;
        target.allowed = {initial};
        target.confirmable = {initial};
        if (loss_on()) target.safe = static_cast<std::uint16_t>(module.safe & info.mask);
        targets_.push_back(std::move(target));
    }
    if (loss_on()) {
        // The gateway counts the silence from its start, which was before ours: a loss is
        // possible until the first request.
        periods_.push_back({Clock::time_point::min(), std::nullopt, std::nullopt, 0});
        period_open_ = true;
    }
    read_histogram_.assign(histogram_bins, 0);
    write_histogram_.assign(histogram_bins, 0);
}

Workload::~Workload() {
    if (!stop_) (void)finish();
}

Result<> Workload::start() {
    auto clock = sim_clock(settings_.sim_control);
    if (!clock) return Unexpected(clock.error());
    sim_clock_ = *clock;
    checker_control_ = std::make_unique<sim::ControlClient>();
    // The checker cannot judge anything without the simulator's log, and a simulator kept from
    // the CPU (its own loop reads a pty: the kernel's tty worker) can take seconds to answer on a
    // machine whose cores are busy: this bound catches a hang, not a slow answer.
    if (auto connected = checker_control_->connect(settings_.sim_control, std::chrono::seconds(60));
        !connected)
        return connected;
    // The log is not cleared: the commands from before the start (the gateway setting the
    // outputs to `initial`) are part of what the device had.
    started_ = Clock::now();
    inputs_ = std::thread([this] { run_inputs(); });
    for (int i = 0; i < settings_.clients; ++i)
        clients_.emplace_back([this, i] { run_client(i); });
    checker_ = std::thread([this] { run_checker(); });
    return {};
}

bool Workload::write_in_flight() const {
    return write_in_flight_.load() > 0;
}

std::uint64_t Workload::writes_failed() const {
    return writes_failed_.load();
}

Report Workload::finish() {
    stop_ = true;
    {
        std::lock_guard lock(gate_mutex_);  // a client held by silence() sees stop_ now
    }
    gate_.notify_all();
    for (auto& client : clients_)
        if (client.joinable()) client.join();
    inputs_stop_ = true;
    if (inputs_.joinable()) inputs_.join();
    if (checker_.joinable()) checker_.join();
    std::lock_guard lock(check_mutex_);
    if (checker_control_) {
        check();
        // Windows still open: every client has stopped, so they all have ended.
        for (auto& target : targets_)
            finalize_windows(target, Clock::time_point::max());
    }
    return current_report();
}

Report Workload::snapshot() const {
    std::lock_guard lock(check_mutex_);
    return current_report();
}

Report Workload::current_report() const {
    auto report = report_;
    report.read_latency = latency_of(read_histogram_, max_read_latency_);
    report.write_latency = latency_of(write_histogram_, max_write_latency_);
    {
        std::lock_guard lock(inputs_mutex_);
        report.input_states = input_states_;
    }
    return report;
}

void Workload::problem(std::uint64_t Report::*counter, std::string text) {
    // The first few of every kind: one kind in bulk must not hide another.
    if (++(report_.*counter) <= problems_per_kind && report_.problems.size() < max_problems)
        report_.problems.push_back(std::move(text));
}

// --- Input driver ---------------------------------------------------------------------------

void Workload::run_inputs() {
    sim::ControlClient control;
    if (auto connected = control.connect(settings_.sim_control); !connected) return;
    std::uint32_t n = 0;
    while (!inputs_stop_) {
        const auto period_start = Clock::now();
        ++n;
        for (int m = 0; m < input_module_count && !inputs_stop_; ++m) {
            const auto words = input_state(m, n);
            const auto& module = modules[static_cast<std::size_t>(m)];
            std::string command = "set " + sim_name(module.address);
            for (int w = 0; w < module.words; ++w)
                command += fmt::format(" {}", words[static_cast<std::size_t>(w)]);
            const auto before = Clock::now();
            const auto reply = control.command(command);
            const auto after = Clock::now();
            if (!reply) continue;  // never set: never expected
            std::lock_guard lock(inputs_mutex_);
            auto& history = input_history_[static_cast<std::size_t>(m)];
            input_index_[static_cast<std::size_t>(m)][words[0]].push_back(history.size());
            history.push_back({before, after, words});
            ++input_states_;
        }
        const auto next = period_start + settings_.input_period;
        while (!inputs_stop_ && Clock::now() < next)
            std::this_thread::sleep_for(std::min<Clock::duration>(next - Clock::now(), 5ms));
    }
}

// --- Clients --------------------------------------------------------------------------------

namespace {

struct ModbusFree {
    void operator()(modbus_t* context) const {
        modbus_close(context);
        modbus_free(context);
    }
};
using Context = std::unique_ptr<modbus_t, ModbusFree>;

int outcome_of(int rc) {
    if (rc >= 0) return 0;
    const int err = errno;
    if (err > MODBUS_ENOBASE && err <= MODBUS_ENOBASE + 11) return err - MODBUS_ENOBASE;
    return -err;
}

}  // namespace

void Workload::run_client(int index) {
    std::mt19937_64 random(settings_.seed * 1000003 + static_cast<std::uint64_t>(index));
    auto& slot = *slots_[static_cast<std::size_t>(index)];
    std::vector<int> owned;
    for (int job = 0; job < static_cast<int>(all_jobs.size()); ++job)
        if (job % settings_.clients == index && (job != 0 || settings_.write_dom16_0))
            owned.push_back(job);
    // What this client believes each of its targets holds: the last value acknowledged.
    std::vector<std::uint16_t> desired;
    for (const auto& target : targets_)
        desired.push_back(target.allowed.front());
    std::uint16_t next_word = static_cast<std::uint16_t>(0x1000 + index * 0x800);

    const auto connect = [&]() -> Context {
        while (!stop_) {
            Context context(modbus_new_tcp("127.0.0.1", static_cast<int>(settings_.port)));
            if (!context) return nullptr;
            const auto timeout = settings_.response_timeout.count();
            modbus_set_response_timeout(context.get(), static_cast<std::uint32_t>(timeout / 1000),
                                        static_cast<std::uint32_t>(timeout % 1000 * 1000));
            modbus_set_slave(context.get(), 1);
            // libmodbus select()s on its socket: a descriptor above FD_SETSIZE would overflow
            // its fd_set (a test may hold more than 1024 descriptors).
            if (modbus_connect(context.get()) == 0 && modbus_get_socket(context.get()) < FD_SETSIZE)
                return context;
            std::this_thread::sleep_for(20ms);
        }
        return nullptr;
    };
    auto context = connect();
    while (!stop_ && context) {
        Op op;
        const bool write = !owned.empty() && std::uniform_real_distribution<double>(0, 1)(random) <
                                                 settings_.write_share;
        std::array<std::uint16_t, 2> values{};  // the job's new values, whole words
        int rc = 0;
        {
            // Held while silence() has closed the gate. Published before `sent` is taken: the
            // checker's horizon never passes a request that is still out (see check()), and
            // silence() never misses one that is about to go.
            std::unique_lock lock(gate_mutex_);
            gate_.wait(lock, [&] { return !gate_closed_ || stop_; });
            if (stop_) break;
            slot.in_flight.store(Clock::now().time_since_epoch().count());
        }
        if (write) {
            op.write = true;
            op.kind =
                owned[std::uniform_int_distribution<std::size_t>(0, owned.size() - 1)(random)];
            const auto& job = all_jobs[static_cast<std::size_t>(op.kind)];
            const auto first = static_cast<std::size_t>(job.targets[0]);
            const bool multiple = std::uniform_int_distribution<int>(0, 1)(random) == 1;
            ++write_in_flight_;
            if (op.kind == 0 || op.kind == 17) {
                // Unique words, so that each one names its write in the simulator's log; never
                // an initial or a safe value, so that those name the gateway's.
                do {
                    values[0] = next_word++;
                    values[1] = static_cast<std::uint16_t>(values[0] ^ 0xFFFF);
                } while (values[0] == desired[first] ||
                         (op.kind == 0
                              ? reserved_word(5, values[0])
                              : reserved_word(7, values[0]) || reserved_word(8, values[1])));
                op.words = {values[0], values[1]};
                op.sent = Clock::now();
                rc = op.kind == 17 ? modbus_write_registers(context.get(), 2, 2, values.data())
                     : multiple    ? modbus_write_registers(context.get(), 0, 1, values.data())
                                   : modbus_write_register(context.get(), 0, values[0]);
            } else if (op.kind <= 16) {
                const int bit = op.kind - 1;
                const auto mask = all_targets[first].mask;
                const std::uint8_t on = (desired[first] & mask) != 0 ? 0 : 1;
                op.words[0] = on != 0 ? mask : 0;
                op.sent = Clock::now();
                rc = multiple ? modbus_write_bits(context.get(), 16 + bit, 1, &on)
                              : modbus_write_bit(context.get(), 16 + bit, on);
            } else {
                const bool rgb = op.kind == 18;
                std::uint16_t value = 0;
                do {
                    value = rgb ? static_cast<std::uint16_t>(
                                      std::uniform_int_distribution<int>(0, 7)(random))
                                : static_cast<std::uint16_t>(
                                      std::uniform_int_distribution<int>(0, 7)(random) << 8 |
                                      std::uniform_int_distribution<int>(0, 7)(random));
                } while (value == desired[first]);
                op.words[0] = value;
                op.sent = Clock::now();
                rc = modbus_write_register(context.get(), rgb ? 8 : 16, value);
            }
            op.received = Clock::now();
            op.outcome = outcome_of(rc);
            if (op.outcome > 0) ++writes_failed_;
            --write_in_flight_;
            if (op.outcome == 0)
                for (std::size_t t = 0; t < job.targets.size(); ++t) {
                    auto& held = desired[static_cast<std::size_t>(job.targets[t])];
                    const auto mask = all_targets[static_cast<std::size_t>(job.targets[t])].mask;
                    held = static_cast<std::uint16_t>((held & ~mask) | op.words[t]);
                }
        } else {
            op.kind = std::uniform_int_distribution<int>(
                0, static_cast<int>(read_kinds.size()) - 1)(random);
            const auto& kind = read_kinds[static_cast<std::size_t>(op.kind)];
            std::array<std::uint16_t, 32> registers{};
            std::array<std::uint8_t, 16> bits{};
            op.sent = Clock::now();
            switch (kind.table) {
                case Table::coils:
                    rc = modbus_read_bits(context.get(), kind.address, kind.count, bits.data());
                    break;
                case Table::discrete_inputs:
                    rc = modbus_read_input_bits(context.get(), kind.address, kind.count,
                                                bits.data());
                    break;
                case Table::holding_registers:
                    rc = modbus_read_registers(context.get(), kind.address, kind.count,
                                               registers.data());
                    break;
                case Table::input_registers:
                    rc = modbus_read_input_registers(context.get(), kind.address, kind.count,
                                                     registers.data());
                    break;
            }
            op.received = Clock::now();
            op.outcome = outcome_of(rc);
            if (op.outcome == 0) {
                if (kind.table == Table::coils || kind.table == Table::discrete_inputs) {
                    std::uint16_t word = 0;
                    for (int b = 0; b < 16; ++b)
                        if (bits[static_cast<std::size_t>(b)] != 0)
                            word = static_cast<std::uint16_t>(word | 1U << b);
                    op.words[0] = word;
                } else {
                    std::copy_n(registers.begin(), op.words.size(), op.words.begin());
                }
                if (op.kind == diagnostics_kind)
                    op.loss_register =
                        registers[static_cast<std::size_t>(loss_register - kind.address)];
            }
        }
        slot.last_sent.store(op.sent.time_since_epoch().count());
        slot.last_received.store(op.received.time_since_epoch().count());
        {
            std::lock_guard lock(slot.mutex);
            slot.done.push_back(op);
        }
        slot.in_flight.store(no_request);
        ++completed_;
        if (op.outcome < 0) {
            // No answer: the connection is in an unknown state (a late response would be taken
            // for the next request's), so start a new one.
            context.reset();
            context = connect();
        }
        const auto pause = std::chrono::microseconds(
            std::uniform_int_distribution<long long>(0, settings_.pause.count())(random));
        if (pause.count() > 0) std::this_thread::sleep_for(pause);
    }
}

// --- Communication loss ---------------------------------------------------------------------

Result<Workload::Silence> Workload::silence(
    std::chrono::milliseconds length, const std::function<void(Clock::time_point)>& meanwhile) {
    if (!loss_on()) return fail(Errc::invalid_argument, "silence(): comm_loss_timeout is off");
    // Our own connection, made before the silence: a connection is not a request.
    Context context(modbus_new_tcp("127.0.0.1", static_cast<int>(settings_.port)));
    if (!context) return fail(Errc::io_error, "silence(): no libmodbus context");
    const auto timeout = settings_.response_timeout.count();
    modbus_set_response_timeout(context.get(), static_cast<std::uint32_t>(timeout / 1000),
                                static_cast<std::uint32_t>(timeout % 1000 * 1000));
    modbus_set_slave(context.get(), 1);
    if (modbus_connect(context.get()) != 0 || modbus_get_socket(context.get()) >= FD_SETSIZE)
        return fail(Errc::io_error,
                    fmt::format("silence(): cannot connect: {}", modbus_strerror(errno)));

    Silence result;
    Clock::time_point held;
    {
        std::lock_guard lock(gate_mutex_);
        gate_closed_ = true;
        held = Clock::now();
        result.writes_in_flight = write_in_flight_.load();
    }
    const auto open_gate = [&] {
        {
            std::lock_guard lock(gate_mutex_);
            gate_closed_ = false;
        }
        gate_.notify_all();
    };
    if (meanwhile) meanwhile(held);
    // Every request that went out before the gate closed is answered (a write to a slow module
    // may take seconds): from then on nothing is sent.
    const auto client_slots = std::span(slots_).first(static_cast<std::size_t>(settings_.clients));
    const auto give_up = Clock::now() + 30s;
    while (std::ranges::any_of(client_slots,
                               [](const auto& slot) { return slot->in_flight != no_request; })) {
        if (Clock::now() >= give_up || stop_) {
            open_gate();
            return fail(Errc::timeout, "silence(): a request was not answered within 30 s");
        }
        std::this_thread::sleep_for(5ms);
    }
    Clock::time_point last_sent{};
    auto drained = held;
    for (const auto& slot : client_slots) {
        last_sent = std::max(last_sent, Clock::time_point(Clock::duration(slot->last_sent)));
        drained = std::max(drained, Clock::time_point(Clock::duration(slot->last_received)));
    }
    // The gateway declares the loss at its last request plus the timeout: past that, with a
    // margin for a busy machine, and `length` past the last answer.
    const auto until =
        std::max(last_sent + settings_.comm_loss_timeout + settings_.slack, drained + length);
    while (!stop_ && Clock::now() < until)
        std::this_thread::sleep_for(std::min<Clock::duration>(until - Clock::now(), 5ms));

    // The first request after the silence and the second, both reads of the diagnostics.
    auto& slot = *slots_.back();
    for (int order = 1; order <= 2; ++order) {
        Op op;
        op.kind = diagnostics_kind;
        op.after_silence = order;
        op.quiet_from = last_sent;
        op.drained = drained;
        const auto& kind = read_kinds[static_cast<std::size_t>(diagnostics_kind)];
        std::array<std::uint16_t, 32> registers{};
        slot.in_flight.store(Clock::now().time_since_epoch().count());
        op.sent = Clock::now();
        const int rc =
            modbus_read_input_registers(context.get(), kind.address, kind.count, registers.data());
        op.received = Clock::now();
        op.outcome = outcome_of(rc);
        if (op.outcome == 0)
            op.loss_register = registers[static_cast<std::size_t>(loss_register - kind.address)];
        if (order == 1)
            result.length =
                std::chrono::duration_cast<std::chrono::milliseconds>(op.sent - last_sent);
        (order == 1 ? result.first : result.second) = op.loss_register;
        slot.last_sent.store(op.sent.time_since_epoch().count());
        {
            std::lock_guard lock(slot.mutex);
            slot.done.push_back(op);
        }
        slot.in_flight.store(no_request);
        ++completed_;
    }
    open_gate();
    std::lock_guard lock(check_mutex_);
    ++report_.silences;
    report_.writes_in_flight_at_silence += static_cast<std::uint64_t>(result.writes_in_flight);
    return result;
}

// --- Checker --------------------------------------------------------------------------------

void Workload::run_checker() {
    while (!stop_) {
        const auto next = Clock::now() + 200ms;
        while (!stop_ && Clock::now() < next)
            std::this_thread::sleep_for(10ms);
        std::lock_guard lock(check_mutex_);
        check();
    }
}

void Workload::finalize_windows(Target& target, Clock::time_point until) {
    while (!target.windows.empty() && target.windows.front().received <= until) {
        const auto window = target.windows.front();
        target.windows.pop_front();
        switch (window.outcome) {
            case Window::Outcome::acknowledged:
                if (window.seen == 0)
                    problem(&Report::lost_writes,
                            fmt::format(
                                "lost write: {} bits {:04X} = {:04X} acknowledged "
                                "(sent at {:.1f} ms, answered at {:.1f} ms) but never "
                                "applied by the device in between",
                                to_string(
                                    modules[static_cast<std::size_t>(target.info.module)].address),
                                target.info.mask, window.value, ms_since(started_, window.sent),
                                ms_since(started_, window.received)));
                // The device keeps it, unless the safe state came after it (a comm loss declared
                // after the write reached the gateway).
                target.allowed = {window.seen > 0 && target.safe &&
                                          (target.safe_seen_at > window.last_seen ||
                                           target.expired_at > window.last_seen)
                                      ? *target.safe
                                      : window.value};
                target.settled_sent = window.sent;
                // Sent after the silence ended: the gateway had pushed the safe state (if it
                // declared a loss) before this write, which is the desired state now.
                if (target.safe_possible) {
                    const auto& ended = periods_[target.period].until;
                    if (ended && window.sent >= *ended) target.safe_possible = false;
                }
                break;
            case Window::Outcome::failed:
                target.last_failed = window.value;
                if (window.spans_modules) target.allowed.push_back(window.value);
                // Only a write answered 0B leaves transmissions behind: an error ack means the
                // device read the command. Any 0B, not only one as long as its timeouts: an
                // attempt that took a starved device's late answer to an earlier request for a
                // malformed one failed at once, its command still unread (a 0B for a closed port
                // sent nothing, or nothing that is read later). None are left when the device
                // has read one and then another request: its attempts went out back to back.
                if (!window.timed_out || window.seen > settings_.retries) break;
                if (window.seen == 0)
                    target.late.push_back(LateTransmissions{window.value, settings_.retries + 1,
                                                            window.received, std::nullopt});
                else if (window.last_seen_request == requests_read_)
                    target.late.push_back(
                        LateTransmissions{window.value, settings_.retries + 1 - window.seen,
                                          window.received, window.last_seen_word});
                break;
            case Window::Outcome::unknown:
                target.allowed.push_back(window.value);
                break;
        }
    }
}

void Workload::apply_command(Target& target, Clock::time_point at, std::uint16_t value) {
    finalize_windows_before(target, at);
    const auto bits = static_cast<std::uint16_t>(value & target.info.mask);
    const auto allowed = std::ranges::find(target.allowed, bits) != target.allowed.end();
    const bool inside = !target.windows.empty() && target.windows.front().sent <= at;
    const auto what = [&] {
        return to_string(modules[static_cast<std::size_t>(target.info.module)].address);
    };
    // The next attempt of a failed write whose late transmissions the device is reading: they
    // went out one after the other, before anything the gateway sent later.
    if (!target.late.empty() && target.late.front().word && *target.late.front().word == value &&
        target.late.front().remaining > 0) {
        --target.late.front().remaining;
        ++report_.failed_writes_applied_late;
        return;
    }
    if (inside && bits == target.windows.front().value) {
        auto& window = target.windows.front();
        if (window.after_safe && !window.overwritten) {
            window.overwritten = true;
            problem(&Report::wrong_values,
                    fmt::format("safe state overwritten: {} bits {:04X} = {:04X}, a write sent at "
                                "{:.1f} ms, before the comm loss, reached the device at {:.1f} ms, "
                                "after the safe push had begun",
                                what(), target.info.mask, bits, ms_since(started_, window.sent),
                                ms_since(started_, at)));
        }
        // Or an attempt of an earlier failed write of the same value, answered before this
        // write was sent: on the line, those attempts came before this write's.
        const auto late = std::ranges::find_if(target.late, [&](const LateTransmissions& l) {
            return l.answered <= window.sent && bits == l.value && l.remaining > 0 &&
                   (!l.word || *l.word == value);
        });
        if (late != target.late.end()) {
            --late->remaining;
            late->word = value;
            target.late.erase(target.late.begin(), late);
            ++window.maybe_late;
        }
        ++window.seen;  // the write itself
        window.last_seen = at;
        window.last_seen_request = requests_read_ + 1;
        window.last_seen_word = value;
        return;
    }
    // Before the rest: the owner may have sent its next write before the late transmission of
    // the one that failed reached the device. Allowed or not: a request spanning two modules
    // leaves its failed value allowed, yet its late transmission is no desired state.
    // The first failed write this can be an attempt of; the attempts of those before it were
    // sent before it, so they are over.
    const auto late = std::ranges::find_if(target.late, [&](const LateTransmissions& l) {
        return bits == l.value && l.remaining > 0 && (!l.word || *l.word == value);
    });
    if (late != target.late.end()) {
        --late->remaining;
        late->word = value;
        target.late.erase(target.late.begin(), late);
        ++report_.failed_writes_applied_late;
        return;
    }
    // The safe state, after a possible comm loss: the push, or a refresh or restore of it.
    if (target.safe_possible && bits == target.safe) {
        // Where nobody writes the safe word and the device had another, the push has begun:
        // every module's desired state is safe from now on.
        if (safe_word_unique(target.info.module) && !allowed) push_began(at);
        target.safe_seen_at = at;
        if (!inside) {
            target.allowed = {bits};
            target.late.clear();
        }
        return;
    }
    if (inside) {
        auto& window = target.windows.front();
        // Everything the device took inside this window carrying its value can have been late
        // transmissions of the owner's earlier failed writes of the same value (maybe_late),
        // which the desired (old) value may follow before this write is sent. The failed writes
        // after those may still have attempts to come: the queue stays.
        if (allowed && window.seen > 0 && window.seen <= window.maybe_late) {
            report_.failed_writes_applied_late += static_cast<std::uint64_t>(window.seen);
            window.seen = 0;
            window.maybe_late = 0;
            return;
        }
        // An acknowledged write that reached the device keeps it until its owner's next write
        // or a safe state after it: a refresh of the old value now undid it.
        if (allowed && window.outcome == Window::Outcome::acknowledged && window.seen > 0 &&
            !window.overwritten) {
            window.overwritten = true;
            problem(&Report::lost_writes,
                    fmt::format("lost write: {} bits {:04X} = {:04X} (sent at {:.1f} ms) reached "
                                "the device, then {:04X} overwrote it at {:.1f} ms, before its "
                                "answer",
                                what(), target.info.mask, window.value,
                                ms_since(started_, window.sent), bits, ms_since(started_, at)));
        }
        if (allowed) return;  // a refresh of the old value while the write waits
    } else if (allowed) {
        // The desired value, but not proof that the gateway has moved on: a starved device
        // reads what was sent before a failed write's attempts after its answer. The order of
        // the line says when its late transmissions are over (read_request, fence).
        target.allowed = {bits};
        return;
    }
    if (target.last_failed && bits == *target.last_failed)
        problem(&Report::failed_writes_pushed,
                fmt::format("failed write pushed: {} bits {:04X} = {:04X} was answered with an "
                            "exception, yet the device was sent it at {:.1f} ms",
                            what(), target.info.mask, bits, ms_since(started_, at)));
    else
        problem(&Report::wrong_values,
                fmt::format("wrong state: {} bits {:04X} = {:04X} sent to the device at {:.1f} ms, "
                            "expected {:04X}",
                            what(), target.info.mask, bits, ms_since(started_, at),
                            target.allowed.empty() ? 0 : target.allowed.front()));
    target.allowed.push_back(bits);  // report a wrong state once, not every refresh after it
}

// Every request the device read, for every target, in the line's order.
void Workload::read_request(Target& target, const Applied& request) {
    finalize_windows_before(target, request.at);
    const bool own = request.module == target.info.module;
    // A command carrying a write's unique word (run_client): the gateway sent it after the
    // client sent the write, and after everything the device read before it.
    if (own && request.applied && unique_words(target.info.module) && !target.windows.empty()) {
        const auto& window = target.windows.front();
        if (window.sent <= request.at && request.value == window.value) fence(window.sent);
    }
    if (!target.late.empty() && target.late.front().word &&
        !(own && request.applied && request.value == *target.late.front().word &&
          target.late.front().remaining > 0))
        target.late.pop_front();  // its attempts, one after the other on the line, are over
    if (own && request.applied) apply_command(target, request.at, request.value);
}

// Everything the device reads from now on was sent by the gateway after `sent`: a failed write
// answered before then has no transmission left to come.
void Workload::fence(Clock::time_point sent) {
    for (auto& target : targets_)
        std::erase_if(target.late,
                      [&](const LateTransmissions& late) { return late.answered < sent; });
}

void Workload::finalize_windows_before(Target& target, Clock::time_point at) {
    while (!target.windows.empty() && target.windows.front().received < at)
        finalize_windows(target, target.windows.front().received);
}

bool Workload::checked(int module) const {
    return module != 5 || settings_.write_dom16_0;
}

void Workload::check() {
    // The horizon: every request sent before it has been answered (or has failed) and is in a
    // slot's list, and every command the device applied before it is in the simulator's log.
    const auto now = Clock::now();
    auto horizon = now;
    for (const auto& slot : slots_) {
        const auto sent = slot->in_flight.load();
        if (sent != no_request)
            horizon = std::min(horizon, Clock::time_point(Clock::duration(sent)));
    }
    const auto log = checker_control_->command("log take");
    if (!log) {
        problem(&Report::transport_errors,
                fmt::format("the simulator's log could not be read: {}", log.error().message));
        return;
    }
    // Commands the device acknowledged: "<µs> <request> 1".
    std::vector<Applied> commands = std::move(carried_commands_);
    carried_commands_.clear();
    std::istringstream lines(*log);
    std::string line;
    while (std::getline(lines, line)) {
        std::istringstream fields(line);
        std::int64_t at = 0;
        std::string request;
        std::string answer;
        if (!(fields >> at >> request)) continue;  // the count after "ok"
        // Every request counts for the order of the line, answered or not ("<µs> <request>").
        const bool answered = static_cast<bool>(fields >> answer);
        if (answered) ++report_.transactions;
        const auto parsed = parse_request(request);
        const auto module =
            parsed && is_output(parsed->module.type) ? module_index(parsed->module) : std::nullopt;
        commands.push_back({sim_clock_.at(at), module.value_or(-1),
                            module ? parsed->output_value : std::uint16_t{0},
                            module && answered && answer == "1"});
    }
    // Stable: one read of the simulator's gives every request in it the same time, and their
    // order is the line's.
    std::ranges::stable_sort(commands, {}, &Applied::at);
    const auto later =
        std::ranges::find_if(commands, [&](const Applied& a) { return a.at > horizon; });
    carried_commands_.assign(later, commands.end());
    commands.erase(later, commands.end());

    // Every client's finished requests.
    for (std::size_t c = 0; c < slots_.size(); ++c) {
        std::lock_guard lock(slots_[c]->mutex);
        auto& done = slots_[c]->done;
        if (loss_on())
            for (const auto& op : done)
                record_request(op);
        carried_[c].insert(carried_[c].end(), done.begin(), done.end());
        done.clear();
    }
    if (loss_on()) {
        find_loss_periods(horizon);
        // A silence confirmed by the first request after it: the gateway declared the loss
        // before that request reached it, and (as silence() checks) within the timeout and the
        // slack of the last request before. Once it had, and every write from before had been
        // answered, the push was next, after one transaction at most (a refresh or poll read
        // the plan puts between two writes); or the port was lost, and the safe state is what
        // a reopen restores. From then on (and the slack, for a simulator short of CPU) the
        // old values are gone.
        const auto one_transaction = (settings_.retries + 1) * settings_.timeout + settings_.slack;
        std::erase_if(confirmations_, [&](const Op& op) {
            if (op.received > horizon) return false;
            if (op.outcome != 0 || op.loss_register != 1) return true;
            const auto declared = std::min(
                op.received, op.quiet_from + settings_.comm_loss_timeout + settings_.slack);
            const auto at = std::max(declared, op.drained) + one_transaction;
            for (std::size_t k = periods_.size(); k-- > 0;)
                if (periods_[k].from < op.received) {
                    expiries_.push_back({at, k, op.received});
                    break;
                }
            return true;
        });
    }

    // Writes sent before the horizon have all been answered: their windows go to their targets.
    for (std::size_t c = 0; c < carried_.size(); ++c) {
        auto& ops = carried_[c];
        for (auto& op : ops) {
            if (!op.write || op.sent >= horizon) continue;
            const auto& job = all_jobs[static_cast<std::size_t>(op.kind)];
            const auto latency =
                std::chrono::duration_cast<std::chrono::microseconds>(op.received - op.sent);
            ++report_.writes;
            ++write_histogram_[bin_of(latency)];
            max_write_latency_ = std::max(max_write_latency_, latency);
            auto outcome = Window::Outcome::failed;
            const auto& first = modules[static_cast<std::size_t>(
                all_targets[static_cast<std::size_t>(job.targets[0])].module)];
            if (op.outcome == 0) {
                ++report_.writes_acked;
                outcome = Window::Outcome::acknowledged;
            } else if (op.outcome == MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE) {
                ++report_.writes_04;
            } else if (op.outcome == MODBUS_EXCEPTION_GATEWAY_TARGET) {
                ++report_.writes_0b;
            } else {
                outcome = Window::Outcome::unknown;
                if (op.outcome > 0)
                    problem(&Report::unexpected_exceptions,
                            fmt::format("client {}: write to {} answered exception {:02X}", c,
                                        to_string(first.address), op.outcome));
                else
                    problem(&Report::unanswered_writes,
                            fmt::format("client {}: write to {} sent at {:.1f} ms got no "
                                        "answer: {}",
                                        c, to_string(first.address), ms_since(started_, op.sent),
                                        modbus_strerror(-op.outcome)));
            }
            for (std::size_t t = 0; t < job.targets.size(); ++t) {
                auto& target = targets_[static_cast<std::size_t>(job.targets[t])];
                const bool spans = job.targets.size() > 1;
                const bool timed_out = op.outcome == MODBUS_EXCEPTION_GATEWAY_TARGET;
                target.windows.push_back(
                    {op.sent, op.received, op.words[t], outcome, spans, timed_out, 0});
                // What the image may show from now on: a value the device acknowledged.
                if (outcome != Window::Outcome::failed || spans)
                    target.confirmable.insert(op.words[t]);
            }
            op.kind = -1;  // taken
        }
        std::erase_if(ops, [](const Op& op) { return op.write && op.kind == -1; });
    }

    // The device's requests, in order, against each target's windows.
    for (const auto& command : commands) {
        advance_to(command.at);
        if (command.applied) {
            ++report_.commands_applied;
            applied_[static_cast<std::size_t>(command.module)].try_emplace(command.value,
                                                                           command.at);
        }
        for (auto& target : targets_)
            if (checked(target.info.module)) read_request(target, command);
        ++requests_read_;
        if (command.applied && loss_on()) count_safe_push(command);
    }
    advance_to(horizon);
    for (auto& target : targets_)
        finalize_windows(target, horizon);
    while (!recent_.empty() && recent_.front().first + loss_requests_kept < horizon)
        recent_.pop_front();

    // Reads answered before the horizon.
    std::lock_guard inputs_lock(inputs_mutex_);
    for (std::size_t c = 0; c < carried_.size(); ++c) {
        auto& ops = carried_[c];
        std::erase_if(ops, [&](const Op& op) {
            if (op.write || op.received > horizon) return false;
            check_read(static_cast<int>(c), op);
            return true;
        });
    }
}

void Workload::check_read(int client, const Op& op) {
    const auto& kind = read_kinds[static_cast<std::size_t>(op.kind)];
    const auto latency =
        std::chrono::duration_cast<std::chrono::microseconds>(op.received - op.sent);
    ++report_.reads;
    ++read_histogram_[bin_of(latency)];
    max_read_latency_ = std::max(max_read_latency_, latency);
    if (op.outcome == MODBUS_EXCEPTION_GATEWAY_TARGET && !kind.samples.empty()) {
        ++report_.reads_stale;
        return;
    }
    if (op.outcome > 0) {
        problem(&Report::unexpected_exceptions,
                fmt::format("client {}: read of {} at {} answered exception {:02X}", client,
                            kind.count, kind.address, op.outcome));
        return;
    }
    if (op.outcome < 0) {
        problem(&Report::transport_errors,
                fmt::format("client {}: read sent at {:.1f} ms got no answer: {}", client,
                            ms_since(started_, op.sent), modbus_strerror(-op.outcome)));
        return;
    }
    ++report_.reads_ok;
    if (op.loss_register >= 0) check_loss_register(client, op);
    std::size_t word = 0;
    for (const int m : kind.samples) {
        const auto& module = modules[static_cast<std::size_t>(m)];
        const auto served =
            std::span(op.words).subspan(word, static_cast<std::size_t>(module.words));
        word += static_cast<std::size_t>(module.words);
        if (module.output) {
            if (!checked(m)) continue;
            const auto value = served[0];
            const auto& applied = applied_[static_cast<std::size_t>(m)];
            const auto first = applied.find(value);
            const bool had = value == 0 || (first != applied.end() && first->second < op.received);
            bool confirmed = true;
            for (const auto& target : targets_)
                if (target.info.module == m &&
                    !target.confirmable.contains(
                        static_cast<std::uint16_t>(value & target.info.mask)))
                    confirmed = false;
            if (!had || !confirmed)
                problem(
                    &Report::wrong_values,
                    fmt::format("client {}: {} read {:04X} (answered at {:.1f} ms): {}", client,
                                to_string(module.address), value, ms_since(started_, op.received),
                                !had ? "the device never had it before"
                                     : "no write of it was acknowledged"));
            continue;
        }
        const auto& history = input_history_[static_cast<std::size_t>(m)];
        const auto& index = input_index_[static_cast<std::size_t>(m)];
        std::optional<std::size_t> best;
        if (const auto found = index.find(served[0]); found != index.end())
            for (const auto k : found->second) {
                const auto& state = history[k];
                if (state.set_after < op.received &&
                    std::equal(served.begin(), served.end(), state.words.begin()))
                    best = std::max(best.value_or(0), k);
            }
        auto& newest =
            newest_served_[static_cast<std::size_t>(client)][static_cast<std::size_t>(m)];
        if (!best) {
            problem(
                &Report::wrong_values,
                fmt::format("client {}: {} read {:04X} {:04X} {:04X} (answered at {:.1f} ms): "
                            "not a state the device had",
                            client, to_string(module.address), served[0],
                            served.size() > 1 ? served[1] : 0, served.size() > 2 ? served[2] : 0,
                            ms_since(started_, op.received)));
        } else if (*best < newest) {
            problem(&Report::wrong_values,
                    fmt::format("client {}: {} read state {} after it had been served state {}: "
                                "back in time",
                                client, to_string(module.address), *best, newest));
        } else {
            newest = *best;
        }
    }
}

// --- Communication loss checks --------------------------------------------------------------

void Workload::record_request(const Op& op) {
    if (op.outcome < 0) return;  // no answer: it may never have reached the gateway
    const auto timeout = settings_.comm_loss_timeout;
    // It reached the gateway between `sent` and `received`: no loss can be declared in
    // [received, sent + timeout).
    if (op.received - op.sent < timeout) excluded_.emplace_back(op.received, op.sent + timeout);
    recent_.emplace_back(op.sent, op.received);
    if (op.after_silence == 1) confirmations_.push_back(op);
}

void Workload::find_loss_periods(Clock::time_point horizon) {
    // Every request sent before the horizon is known, so what is excluded before it is final.
    std::ranges::sort(excluded_);
    std::size_t used = 0;
    for (; used < excluded_.size() && excluded_[used].first <= horizon; ++used) {
        const auto [from, to] = excluded_[used];
        if (period_open_) {
            periods_.back().until = from;
            period_open_ = false;
            covered_until_ = to;
        } else if (from > covered_until_) {
            periods_.push_back({covered_until_, from, std::nullopt, 0});
            ++report_.possible_losses;
            covered_until_ = to;
        } else {
            covered_until_ = std::max(covered_until_, to);
        }
    }
    excluded_.erase(excluded_.begin(), excluded_.begin() + static_cast<std::ptrdiff_t>(used));
    if (!period_open_ && horizon > covered_until_) {
        periods_.push_back({covered_until_, std::nullopt, std::nullopt, 0});
        ++report_.possible_losses;
        period_open_ = true;
    }
}

void Workload::advance_to(Clock::time_point at) {
    for (;;) {
        const bool period_due = activated_ < periods_.size() && periods_[activated_].from <= at;
        const auto expiry = std::ranges::min_element(expiries_, {}, &Expiry::at);
        const bool expiry_due = expiry != expiries_.end() && expiry->at <= at;
        if (period_due && (!expiry_due || periods_[activated_].from <= expiry->at)) {
            activate(activated_++);
        } else if (expiry_due) {
            const auto due = *expiry;
            expiries_.erase(expiry);
            expire(due);
        } else {
            return;
        }
    }
}

void Workload::activate(std::size_t period) {
    const auto from = periods_[period].from;
    for (auto& target : targets_) {
        if (!target.safe || !checked(target.info.module)) continue;
        finalize_windows_before(target, from);
        target.safe_possible = true;
        target.period = period;
        target.confirmable.insert(*target.safe);  // the image shows it once the device took it
    }
}

void Workload::expire(const Expiry& expiry) {
    const auto from = periods_[expiry.period].from;
    const auto bound = arrival_bound(settings_.comm_loss_timeout);
    for (auto& target : targets_) {
        if (!target.safe || !checked(target.info.module)) continue;
        finalize_windows_before(target, expiry.at);
        if (target.settled_sent >= expiry.boundary) continue;  // written after the loss since
        target.allowed = {*target.safe};
        const bool open = !target.windows.empty() && target.windows.front().sent <= expiry.at;
        if (!open) {
            target.expired_at = expiry.at;
            continue;
        }
        // A write still waiting for its answer: from before the loss, it applied before the
        // push or never; from after, it decides when it is answered.
        auto& window = target.windows.front();
        if (window.sent + bound < from) {
            target.expired_at = expiry.at;
            if (window.outcome == Window::Outcome::acknowledged && window.seen == 0)
                window.after_safe = true;
        }
    }
}

void Workload::push_began(Clock::time_point at) {
    if (activated_ == 0) return;
    auto& period = periods_[activated_ - 1];
    if (period.push_seen) return;
    period.push_seen = at;
    expire({at, activated_ - 1, Clock::time_point::max()});
}

void Workload::count_safe_push(const Applied& command) {
    const auto m = static_cast<std::size_t>(command.module);
    const auto before = std::exchange(module_value_[m], command.value);
    if (activated_ == 0 || !checked(command.module) || command.value != modules[m].safe ||
        before == command.value)
        return;
    // Not the gateway's when some target of the module took it as a client's write, or when no
    // loss is possible for it.
    bool possible = false;
    for (const auto& target : targets_) {
        if (target.info.module != command.module) continue;
        possible = possible || target.safe_possible;
        if (!target.windows.empty() && target.windows.front().seen > 0 &&
            target.windows.front().last_seen == command.at)
            return;
    }
    auto& period = periods_[activated_ - 1];
    const auto bit = 1U << m;
    if (!possible || (period.modules_pushed & bit) != 0) return;
    period.modules_pushed |= bit;
    ++report_.safe_pushes;
}

void Workload::check_loss_register(int client, const Op& op) {
    const int value = op.loss_register;
    if (op.after_silence == 1) {
        if (value == 1)
            ++report_.silences_signalled;
        else
            problem(&Report::wrong_values,
                    fmt::format("comm loss not signalled: the first request after a silence of "
                                "the timeout and more (sent at {:.1f} ms) read 1020 = {}",
                                ms_since(started_, op.sent), value));
    }
    if (op.after_silence == 2 && value == 0) ++report_.silences_cleared;
    if (value == 0) return;
    std::optional<std::size_t> period;
    if (value == 1)
        for (std::size_t k = periods_.size(); k-- > 0;)
            if (periods_[k].from < op.received) {
                period = k;
                break;
            }
    if (!period) {
        problem(
            &Report::wrong_values,
            fmt::format("client {}: 1020 read {} (answered at {:.1f} ms) with no silence of the "
                        "timeout before it",
                        client, value, ms_since(started_, op.received)));
        return;
    }
    // The loss was declared before `latest`; a request sent less than a timeout before that,
    // and answered before this one was sent, reached the gateway after the loss (a request
    // from before the loss reached it at least a timeout earlier) and cleared 1020.
    const auto latest =
        std::min(periods_[*period].until.value_or(Clock::time_point::max()), op.received);
    for (const auto& [sent, received] : recent_)
        if (sent >= latest - settings_.comm_loss_timeout && received < op.sent) {
            problem(&Report::wrong_values,
                    fmt::format("client {}: 1020 read 1 (sent at {:.1f} ms), though a request "
                                "sent at {:.1f} ms and answered at {:.1f} ms came after the "
                                "silence: only the first request after a loss reads 1",
                                client, ms_since(started_, op.sent), ms_since(started_, sent),
                                ms_since(started_, received)));
            return;
        }
}

}  // namespace ioport::bench
