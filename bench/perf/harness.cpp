#include "bench/perf/harness.hpp"

#include <fcntl.h>
#include <sched.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "protocol/tags.hpp"

namespace ioport::bench {
namespace {

// The number after `prefix` in `text`, if it is there.
std::optional<std::uint16_t> port_after(const std::string& text, std::string_view prefix) {
    const auto at = text.find(prefix);
    if (at == std::string::npos) return std::nullopt;
    unsigned port = 0;
    bool digits = false;
    for (auto i = at + prefix.size(); i < text.size() && text[i] >= '0' && text[i] <= '9'; ++i) {
        port = port * 10 + static_cast<unsigned>(text[i] - '0');
        digits = true;
    }
    if (!digits || port == 0 || port > 65535) return std::nullopt;
    return static_cast<std::uint16_t>(port);
}

}  // namespace

std::string read_file(const std::string& path) {
    std::ifstream in(path);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

std::chrono::milliseconds Environment::window(std::chrono::milliseconds full) const {
    if (quick) return std::min(full, std::chrono::milliseconds(200));
    return std::chrono::milliseconds(
        static_cast<std::int64_t>(static_cast<double>(full.count()) * scale));
}

Environment Environment::baseline() const {
    auto earlier = *this;
    earlier.binaries.ioportd = binaries.baseline;
    return earlier;
}

void pin_this_thread(std::optional<int> cpu) {
    if (!cpu) return;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(*cpu, &set);
    (void)::sched_setaffinity(0, sizeof set, &set);
}

WakeupLatencyHold::WakeupLatencyHold() {
    fd_ = ::open("/dev/cpu_dma_latency", O_WRONLY | O_CLOEXEC);
    const std::int32_t microseconds = 0;
    if (fd_ >= 0 && ::write(fd_, &microseconds, sizeof microseconds) == sizeof microseconds) return;
    failure_ = fmt::format("/dev/cpu_dma_latency: {}", std::strerror(errno));
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
}

// The kernel drops the request when the descriptor closes.
WakeupLatencyHold::~WakeupLatencyHold() {
    if (fd_ >= 0) ::close(fd_);
}

TempDir::TempDir() {
    std::string pattern =
        (std::filesystem::temp_directory_path() / "ioportd-bench.XXXXXX").string();
    if (::mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = pattern;
}

TempDir::~TempDir() {
    std::error_code ignored;
    std::filesystem::remove_all(path_, ignored);
}

Process::Process(const std::vector<std::string>& argv, std::optional<int> cpu,
                 const std::string& output_path)
    : output_path_(output_path) {
    // Everything the child needs is prepared before fork(): after it, only async-signal-safe
    // calls, since this process has threads.
    std::vector<char*> args;
    args.reserve(argv.size() + 1);
    for (const auto& arg : argv)
        args.push_back(const_cast<char*>(arg.c_str()));
    args.push_back(nullptr);
    cpu_set_t set;
    CPU_ZERO(&set);
    if (cpu) CPU_SET(*cpu, &set);
    const int out = ::open(output_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (out < 0) throw std::runtime_error("cannot create " + output_path);
    pid_ = ::fork();
    if (pid_ == 0) {
        // A benchmark that dies must not leave servers and simulators behind.
        ::prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (cpu) ::sched_setaffinity(0, sizeof set, &set);
        ::dup2(out, STDOUT_FILENO);
        ::dup2(out, STDERR_FILENO);
        ::close_range(3, ~0U, 0);
        ::execv(args[0], args.data());
        ::_exit(127);
    }
    ::close(out);
    if (pid_ < 0) throw std::runtime_error("fork failed");
}

Process::~Process() {
    stop();
}

bool Process::running() const {
    return pid_ > 0 && ::waitpid(pid_, nullptr, WNOHANG) == 0;
}

int Process::stop(std::chrono::milliseconds deadline) {
    if (pid_ <= 0) return -1;
    ::kill(pid_, SIGTERM);
    return wait(deadline);
}

int Process::wait(std::chrono::milliseconds deadline) {
    if (pid_ <= 0) return -1;
    int status = 0;
    const bool exited = wait_for(
        [&] {
            const auto done = ::waitpid(pid_, &status, WNOHANG);
            return done == pid_ || (done < 0 && errno == ECHILD);
        },
        deadline);
    if (!exited) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
    }
    pid_ = -1;
    return exited && WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::string Process::output() const {
    return read_file(output_path_);
}

std::chrono::nanoseconds cpu_time(pid_t pid) {
    const auto tasks = fmt::format("/proc/{}/task", pid);
    std::chrono::nanoseconds total{};
    bool schedstat = false;
    std::error_code ec;
    for (const auto& task : std::filesystem::directory_iterator(tasks, ec)) {
        std::ifstream in(task.path() / "schedstat");
        long long run_ns = 0;
        if (in >> run_ns) {
            total += std::chrono::nanoseconds(run_ns);
            schedstat = true;
        }
    }
    return schedstat ? total : stat_cpu_time(pid);
}

std::uint64_t sleeps(pid_t pid) {
    std::uint64_t total = 0;
    std::error_code ec;
    for (const auto& task :
         std::filesystem::directory_iterator(fmt::format("/proc/{}/task", pid), ec)) {
        std::ifstream in(task.path() / "status");
        std::string line;
        while (std::getline(in, line)) {
            unsigned long long count = 0;
            if (std::sscanf(line.c_str(), "voluntary_ctxt_switches: %llu", &count) == 1)
                total += count;
        }
    }
    return total;
}

std::chrono::nanoseconds stat_cpu_time(pid_t pid) {
    // utime and stime, fields 14 and 15, in clock ticks; the command name may hold spaces.
    const auto stat = read_file(fmt::format("/proc/{}/stat", pid));
    const auto close = stat.rfind(')');
    if (close == std::string::npos) return {};
    std::istringstream fields(stat.substr(close + 2));
    std::string field;
    long long ticks = 0;
    for (int i = 3; i <= 15 && fields >> field; ++i)
        if (i >= 14) ticks += std::stoll(field);
    return std::chrono::nanoseconds(ticks * 1'000'000'000LL / ::sysconf(_SC_CLK_TCK));
}

std::uint64_t minor_faults(pid_t pid) {
    // Field 10; the command name (field 2) may hold spaces.
    const auto stat = read_file(fmt::format("/proc/{}/stat", pid));
    const auto close = stat.rfind(')');
    if (close == std::string::npos) return 0;
    std::istringstream fields(stat.substr(close + 2));
    std::string field;
    for (int i = 3; i <= 10 && fields >> field; ++i)
        if (i == 10) return std::stoull(field);
    return 0;
}

double core_percent(std::chrono::nanoseconds cpu, double seconds) {
    return microseconds(cpu) / 1e4 / seconds;
}

double CpuWindows::percent(std::size_t process) const {
    return core_percent(total.at(process), seconds);
}

CpuWindows cpu_windows(
    const std::vector<pid_t>& pids, int windows, std::chrono::milliseconds window,
    const std::function<void(int)>& before,
    const std::function<void(int, const std::vector<std::chrono::nanoseconds>&, double)>& after) {
    CpuWindows result{std::vector<std::chrono::nanoseconds>(pids.size()), 0};
    std::vector<std::chrono::nanoseconds> cpu(pids.size());
    for (int i = 0; i < windows; ++i) {
        before(i);
        for (std::size_t p = 0; p < pids.size(); ++p)
            cpu[p] = cpu_time(pids[p]);
        const auto start = Clock::now();
        std::this_thread::sleep_for(window);
        for (std::size_t p = 0; p < pids.size(); ++p)
            cpu[p] = cpu_time(pids[p]) - cpu[p];
        const double s = seconds(Clock::now() - start);
        for (std::size_t p = 0; p < pids.size(); ++p)
            result.total[p] += cpu[p];
        result.seconds += s;
        after(i, cpu, s);
    }
    return result;
}

Memory memory(pid_t pid) {
    std::ifstream in(fmt::format("/proc/{}/status", pid));
    Memory m;
    std::string line;
    while (std::getline(in, line)) {
        std::size_t kib = 0;
        if (std::sscanf(line.c_str(), "VmRSS: %zu kB", &kib) == 1) m.rss_kib = kib;
        if (std::sscanf(line.c_str(), "VmHWM: %zu kB", &kib) == 1) m.peak_kib = kib;
    }
    return m;
}

double mib(std::size_t kib) {
    return static_cast<double>(kib) / 1024.0;
}

std::vector<ModuleAddress> modules_of(ModuleType type, int count) {
    std::vector<ModuleAddress> modules;
    modules.reserve(static_cast<std::size_t>(count));
    for (int n = 0; n < count; ++n)
        modules.push_back({type, static_cast<std::uint8_t>(n)});
    return modules;
}

std::vector<ModuleAddress> full_bus() {
    std::vector<ModuleAddress> modules;
    for (const auto type : {ModuleType::dim16, ModuleType::acm3p, ModuleType::acm3c,
                            ModuleType::lim16, ModuleType::dccim, ModuleType::dcvim}) {
        const auto some = modules_of(type);
        modules.insert(modules.end(), some.begin(), some.end());
    }
    return modules;
}

std::vector<ModuleAddress> every_module() {
    std::vector<ModuleAddress> modules;
    for (const auto type : all_module_types) {
        const auto some = modules_of(type);
        modules.insert(modules.end(), some.begin(), some.end());
    }
    return modules;
}

std::string hub_argument(const std::vector<ModuleAddress>& modules) {
    std::string text;
    for (const auto module : modules)
        text += fmt::format("{}{}:{}", text.empty() ? "" : ",", name(module.type), module.number);
    return text;
}

std::size_t transaction_bytes(ModuleAddress module) {
    std::size_t request = 3;                            // "a0\r"
    if (module.type == ModuleType::dom16) request = 7;  // "b0HHHH\r"
    if (module.type == ModuleType::rgbdm) request = 4;  // "f0C\r"
    if (module.type == ModuleType::mux8m) request = 5;  // "i0PN\r"
    return request + reply_length(module.type) + 1;
}

bool is_analog(ModuleType type) {
    return reply_words(type) > 0 && full_scale(type) > 0;
}

std::vector<ModuleAddress> analog_of(const std::vector<ModuleAddress>& modules) {
    std::vector<ModuleAddress> analog;
    for (const auto module : modules)
        if (is_analog(module.type)) analog.push_back(module);
    return analog;
}

std::chrono::nanoseconds wire_time(std::size_t bytes, int baud) {
    return std::chrono::nanoseconds(static_cast<std::int64_t>(bytes) * 10 * 1'000'000'000LL / baud);
}

// ", name: …, channels: {…}" or ", inputs: {…}": every key of §6.1 the module takes.
std::string tags_yaml(ModuleAddress module) {
    std::string yaml =
        fmt::format(R"(, name: "{} {} in cabinet 3")", name(module.type), module.number);
    if (gateway::has_channels(module.type)) {
        yaml += ", channels: {";
        for (int c = 0; c < reply_words(module.type); ++c)
            yaml += fmt::format(R"({} {}: {{ name: "supply temperature {}", unit: "°C", )"
                                R"(scale: [0, {:g}, -20, 150] }})",
                                c == 0 ? "" : ",", c, c, full_scale(module.type));
        yaml += " }";
    }
    if (gateway::has_points(module.type)) {
        yaml += module.type == ModuleType::dom16 ? ", outputs: {" : ", inputs: {";
        for (int k = 0; k < 16; ++k)
            yaml += fmt::format(R"({} {}: "point {} of line 2")", k == 0 ? "" : ",", k, k);
        yaml += " }";
    }
    return yaml;
}

std::string gateway_yaml(const std::vector<LinkSpec>& links, int max_connections, bool http,
                         std::string_view more, std::string_view modbus_more,
                         std::string_view http_more) {
    std::string yaml =
        fmt::format("modbus:\n  listen: \"127.0.0.1:0\"\n  max_connections: {}\n", max_connections);
    yaml += modbus_more;
    if (http) {
        yaml += "http:\n  listen: \"127.0.0.1:0\"\n";
        yaml += http_more;
    }
    yaml += "links:\n";
    for (std::size_t i = 0; i < links.size(); ++i) {
        yaml += fmt::format(
            "  - name: hub{}\n    protocol: ioport\n    device: {}\n    baud: {}\n"
            "    unit_id: {}\n    modules:\n",
            i, links[i].device, links[i].baud, i + 1);
        for (const auto module : links[i].modules)
            yaml += fmt::format("      - {{ type: {}, number: {}{}{} }}\n", name(module.type),
                                module.number,
                                links[i].poll.count() > 0 && !is_output(module.type)
                                    ? fmt::format(", poll: {}ms", links[i].poll.count())
                                    : std::string(),
                                links[i].tags ? tags_yaml(module) : std::string());
    }
    yaml += more;
    return yaml;
}

ModbusConnection::ModbusConnection(std::uint16_t port, int unit,
                                   std::chrono::milliseconds response_timeout)
    : context_(modbus_new_tcp("127.0.0.1", port)) {
    if (context_ == nullptr) return;
    const auto ms = response_timeout.count();
    modbus_set_response_timeout(context_, static_cast<std::uint32_t>(ms / 1000),
                                static_cast<std::uint32_t>(ms % 1000 * 1000));
    modbus_set_slave(context_, unit);
    connected_ = modbus_connect(context_) == 0;
}

ModbusConnection::~ModbusConnection() {
    if (context_ == nullptr) return;
    modbus_close(context_);
    modbus_free(context_);
}

std::optional<std::vector<std::uint16_t>> ModbusConnection::input_registers(int address,
                                                                            int count) {
    std::vector<std::uint16_t> registers(static_cast<std::size_t>(count));
    if (!connected_ ||
        modbus_read_input_registers(context_, address, count, registers.data()) != count)
        return std::nullopt;
    return registers;
}

std::optional<Diagnostics> read_diagnostics(ModbusConnection& connection) {
    const auto r = connection.input_registers(1000, 10);
    if (!r) return std::nullopt;
    const auto u32 = [&](std::size_t i) {
        return static_cast<std::uint32_t>((*r)[i]) << 16 | (*r)[i + 1];
    };
    return Diagnostics{(*r)[0], (*r)[1], u32(2), u32(4), u32(6), u32(8)};
}

Gateway::Gateway(const Environment& env, const TempDir& dir, const std::string& yaml)
    : process_(
          [&] {
              std::ofstream(dir / "ioportd.yaml") << yaml;
              return std::vector<std::string>{env.binaries.ioportd, "--config",
                                              dir / "ioportd.yaml", "--log", "stderr"};
          }(),
          env.placement.server_cpu, dir / "ioportd.log") {
    wait_for(
        [&] {
            port_ = port_after(process_.output(), "Modbus TCP on 127.0.0.1:").value_or(0);
            return port_ != 0 || !process_.running();
        },
        10s);
    if (port_ == 0) fmt::print(stderr, "ioportd did not start; its log:\n{}\n", process_.output());
}

std::uint16_t Gateway::http_port() const {
    std::uint16_t port = 0;
    wait_for(
        [&] {
            // With a web configuration's tls_server_config the port speaks HTTPS only, and the
            // log says so.
            const auto log = process_.output();
            port = port_after(log, "HTTP on http://127.0.0.1:")
                       .value_or(port_after(log, "HTTP on https://127.0.0.1:").value_or(0));
            return port != 0 || !process_.running();
        },
        5s);
    return port;
}

std::uint16_t Gateway::tls_port() const {
    std::uint16_t port = 0;
    wait_for(
        [&] {
            port = port_after(process_.output(), "Modbus/TCP Security (TLS) on 127.0.0.1:")
                       .value_or(0);
            return port != 0 || !process_.running();
        },
        5s);
    return port;
}

bool Gateway::wait_until_polling(int units, std::chrono::milliseconds deadline) const {
    const auto until = Clock::now() + deadline;
    for (int unit = 1; unit <= units; ++unit) {
        ModbusConnection connection(port_, unit);
        const bool polling = wait_for(
            [&] {
                const auto d = read_diagnostics(connection);
                return d && d->link_state == 1 && d->cycles >= 2;
            },
            std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now()));
        if (!polling) {
            fmt::print(stderr, "unit {} of ioportd is not polling every module; its log:\n{}\n",
                       unit, log());
            return false;
        }
    }
    return true;
}

PlainServer::PlainServer(const Environment& env, const TempDir& dir)
    : process_({env.binaries.plain_server, "0"}, env.placement.server_cpu, dir / "plain.log") {
    wait_for(
        [&] {
            port_ = port_after(process_.output(), "listening on port ").value_or(0);
            return port_ != 0 || !process_.running();
        },
        10s);
    if (port_ == 0) fmt::print(stderr, "the plain server did not start: {}\n", process_.output());
}

SimProcess::SimProcess(const Environment& env, const std::string& link,
                       const std::vector<ModuleAddress>& modules,
                       const std::vector<std::string>& options)
    : link_(link),
      process_(
          [&] {
              std::vector<std::string> argv{env.binaries.sim, "--link", link, "--hub",
                                            hub_argument(modules)};
              argv.insert(argv.end(), options.begin(), options.end());
              return argv;
          }(),
          env.placement.client_cpu, link + ".log") {
    ready_ = wait_for([&] { return std::filesystem::exists(link_) || !process_.running(); }, 10s) &&
             process_.running();
    if (!ready_) fmt::print(stderr, "ioport-sim did not start: {}\n", process_.output());
}

sim::SimulatorSettings timed_line(int baud) {
    sim::SimulatorSettings settings;
    settings.baud = baud;
    settings.line_timing = true;
    settings.turnaround = 0us;
    return settings;
}

InProcessSim::InProcessSim(const std::string& link, const std::vector<ModuleAddress>& modules,
                           sim::SimulatorSettings settings, std::optional<int> cpu)
    : settings_(std::move(settings)),
      work_(io_.get_executor()),
      model_(sim::Protocol::ioport, 1),
      ticker_(io_) {
    settings_.link_path = link;
    for (const auto module : modules)
        (void)model_.add(module);
    // The simulator takes its log's origin, steady_clock::now(), while it is constructed.
    const auto before = Clock::now();
    simulator_.emplace(io_, model_, settings_);
    const auto after = Clock::now();
    origin_ = before + (after - before) / 2;
    origin_uncertainty_ = (after - before) / 2;
    if (auto started = simulator_->start(); !started) {
        fmt::print(stderr, "simulator: {}\n", started.error().message);
        return;
    }
    ready_ = true;
    thread_ = std::thread([this, cpu] {
        pin_this_thread(cpu);
        io_.run();
    });
}

InProcessSim::~InProcessSim() {
    if (thread_.joinable()) {
        asio::post(io_, [this] {
            ticker_.cancel();
            simulator_->stop();
            work_.reset();
            io_.stop();
        });
        thread_.join();
    }
}

template <class F>
auto InProcessSim::on_sim_thread(F f) -> decltype(f()) {
    std::packaged_task<decltype(f())()> task(std::move(f));
    auto result = task.get_future();
    asio::post(io_, [&task] { task(); });
    return result.get();
}

std::vector<sim::LogEntry> InProcessSim::take_log() {
    return on_sim_thread([this] {
        std::vector<sim::LogEntry> log(model_.log().begin(), model_.log().end());
        model_.clear_log();
        return log;
    });
}

sim::AnswerErrors InProcessSim::take_answer_errors() {
    return on_sim_thread([this] {
        auto errors = simulator_->answer_errors();
        simulator_->clear_answer_errors();
        return errors;
    });
}

Clock::time_point InProcessSim::set_values(ModuleAddress module, std::vector<std::uint16_t> words) {
    return on_sim_thread([&] {
        (void)model_.set_values(module, words);
        return Clock::now();
    });
}

void InProcessSim::wander(std::vector<ModuleAddress> modules, std::chrono::microseconds period) {
    on_sim_thread([this] { every_word_ = true; });
    tick_values(std::move(modules), period);
}

void InProcessSim::tick_values(std::vector<ModuleAddress> modules,
                               std::chrono::microseconds period) {
    on_sim_thread([&] {
        ticked_ = std::move(modules);
        tick_period_ = period;
        ticker_.expires_after(period);
        ticker_.async_wait([this](const boost::system::error_code& ec) {
            if (!ec) tick();
        });
    });
}

void InProcessSim::tick() {
    ++tick_value_;
    for (const auto module : ticked_) {
        if (!every_word_) {
            const std::array<std::uint16_t, 1> value{tick_value_};
            (void)model_.set_values(module, value);
            continue;
        }
        // Each word its own value, every one of them new at every tick.
        std::array<std::uint16_t, 3> words{};
        for (std::size_t w = 0; w < words.size(); ++w)
            words[w] = static_cast<std::uint16_t>(tick_value_ + std::size_t{0x5555} * w +
                                                  std::size_t{0x0101} * module.number);
        (void)model_.set_values(
            module, std::span(words.data(), static_cast<std::size_t>(reply_words(module.type))));
    }
    ticker_.expires_at(ticker_.expiry() + tick_period_);
    ticker_.async_wait([this](const boost::system::error_code& ec) {
        if (!ec) tick();
    });
}

namespace {

std::chrono::nanoseconds thread_cpu_time() {
    timespec t{};
    ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return std::chrono::seconds(t.tv_sec) + std::chrono::nanoseconds(t.tv_nsec);
}

// The simulator's pty as a minimal master uses it: raw, blocking write() and read() until the CR.
class RawLine {
  public:
    explicit RawLine(const std::string& link)
        : fd_(::open(link.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC)) {
        if (fd_ < 0) return;
        termios tio{};
        ::tcgetattr(fd_, &tio);
        ::cfmakeraw(&tio);
        tio.c_cc[VMIN] = 1;
        tio.c_cc[VTIME] = 0;
        ::tcsetattr(fd_, TCSANOW, &tio);
        ::tcflush(fd_, TCIOFLUSH);
    }
    ~RawLine() {
        if (fd_ >= 0) ::close(fd_);
    }
    RawLine(const RawLine&) = delete;
    RawLine& operator=(const RawLine&) = delete;

    bool is_open() const { return fd_ >= 0; }
    bool transact(const std::string& request) {
        if (::write(fd_, request.data(), request.size()) != static_cast<ssize_t>(request.size()))
            return false;
        for (;;) {
            const auto n = ::read(fd_, buffer_.data(), buffer_.size());
            if (n <= 0) return false;
            if (buffer_[static_cast<std::size_t>(n) - 1] == '\r') return true;
        }
    }

  private:
    int fd_;
    std::array<char, 64> buffer_{};
};

std::vector<std::string> read_requests(const std::vector<ModuleAddress>& modules) {
    std::vector<std::string> requests;
    requests.reserve(modules.size());
    for (const auto module : modules)
        requests.push_back(encode_request(module).value());
    return requests;
}

}  // namespace

RawRate raw_ping_pong(const std::string& link, const std::vector<ModuleAddress>& modules,
                      std::chrono::milliseconds window, std::optional<int> cpu) {
    RawRate rate;
    std::thread client([&] {
        pin_this_thread(cpu);
        RawLine line(link);
        if (!line.is_open()) return;
        const auto requests = read_requests(modules);
        for (const auto& request : requests)  // a cycle to warm up
            line.transact(request);
        std::uint64_t done = 0;
        const auto cpu_before = thread_cpu_time();
        const auto start = Clock::now();
        const auto end = start + window;
        while (Clock::now() < end)
            for (const auto& request : requests) {
                if (!line.transact(request)) ++rate.failed;
                ++done;
            }
        const auto elapsed = seconds(Clock::now() - start);
        rate.per_second = static_cast<double>(done) / elapsed;
        rate.cpu_us_per_transaction =
            microseconds(thread_cpu_time() - cpu_before) / static_cast<double>(done);
    });
    client.join();
    return rate;
}

std::vector<TimedWrite> raw_writes(const std::string& link,
                                   const std::vector<ModuleAddress>& modules, ModuleAddress target,
                                   int count, std::optional<int> cpu) {
    std::vector<TimedWrite> done;
    RawLine line(link);
    if (!line.is_open()) return done;
    std::atomic<bool> pending{false};
    std::atomic<bool> stop{false};
    TimedWrite next;
    std::thread poller([&] {
        pin_this_thread(cpu);
        const auto requests = read_requests(modules);
        while (!stop)
            for (const auto& request : requests) {
                // Between transactions, as ioportd does: a write waiting goes first.
                if (pending.load(std::memory_order_acquire)) {
                    next.ok = line.transact(encode_request(target, next.word).value());
                    next.answered = Clock::now();
                    pending.store(false, std::memory_order_release);
                    pending.notify_one();
                }
                (void)line.transact(request);
            }
    });
    std::mt19937 random(7);
    std::uniform_int_distribution<int> pause_us(2000, 10000);
    std::uint16_t word = 0;
    for (int i = 0; i < count; ++i) {
        std::this_thread::sleep_for(std::chrono::microseconds(pause_us(random)));
        word = static_cast<std::uint16_t>(word ^ (0x1000 + i));
        next = TimedWrite{};
        next.word = word;
        next.sent = Clock::now();
        pending.store(true, std::memory_order_release);
        pending.wait(true);
        done.push_back(next);
    }
    stop = true;
    poller.join();
    return done;
}

double median(std::vector<double> values) {
    if (values.empty()) return 0;
    std::sort(values.begin(), values.end());
    return values[(values.size() - 1) / 2];
}

Summary summarize(std::vector<double> values) {
    Summary s;
    s.count = values.size();
    if (values.empty()) return s;
    std::sort(values.begin(), values.end());
    const auto rank = [&](double q) {
        const auto n = static_cast<double>(values.size());
        const auto i = static_cast<std::size_t>(std::max(1.0, std::ceil(q * n))) - 1;
        return values[std::min(i, values.size() - 1)];
    };
    double sum = 0;
    for (const auto v : values)
        sum += v;
    s.mean = sum / static_cast<double>(values.size());
    s.min = values.front();
    s.max = values.back();
    s.p50 = rank(0.50);
    s.p99 = rank(0.99);
    s.p999 = rank(0.999);
    return s;
}

double microseconds(std::chrono::nanoseconds d) {
    return static_cast<double>(d.count()) / 1000.0;
}

double seconds(Clock::duration d) {
    return std::chrono::duration<double>(d).count();
}

Table::Table(std::vector<std::string> header) : columns_(header.size()) {
    fmt::print("\n| {} |\n|", fmt::join(header, " | "));
    for (std::size_t i = 0; i < columns_; ++i)
        fmt::print("---|");
    fmt::print("\n");
    (void)std::fflush(stdout);
}

void Table::row(const std::vector<std::string>& cells) const {
    fmt::print("| {} |\n", fmt::join(cells, " | "));
    (void)std::fflush(stdout);
}

void machine_line(const std::string& json) {
    fmt::print("BENCH {}\n", json);
    (void)std::fflush(stdout);
}

std::string yes_no(bool met) {
    return met ? "yes" : "**no**";
}

}  // namespace ioport::bench
