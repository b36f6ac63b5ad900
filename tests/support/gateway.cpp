#include "tests/support/gateway.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <cerrno>
#include <fstream>
#include <regex>
#include <sstream>
#include <thread>

#include "tests/support/beside_program.hpp"
#include "tests/support/timing.hpp"

namespace ioport::test {
namespace {

using Clock = std::chrono::steady_clock;
constexpr auto poll_interval = std::chrono::milliseconds(5);

}  // namespace

bool eventually(const std::function<bool()>& condition, std::chrono::milliseconds deadline) {
    const auto until = Clock::now() + deadline;
    for (;;) {
        if (condition()) return true;
        if (Clock::now() >= until) return false;
        std::this_thread::sleep_for(poll_interval);
    }
}

GatewayProcess::GatewayProcess(const std::string& yaml, std::vector<std::string> extra,
                               const std::vector<std::string>& environment)
    : log_path_(dir_ / "ioportd.log") {
    const auto config = config_path();
    rewrite_config(yaml);
    const int log_fd = ::open(log_path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    std::vector<std::string> argv{IOPORTD_BINARY, "--config", config};
    argv.insert(argv.end(), extra.begin(), extra.end());
    pid_ = spawn(argv, log_fd, log_fd, environment);
    ::close(log_fd);
    if (pid_ <= 0) return;
    // "Modbus TCP on 127.0.0.1:40123, ..." once the listener is bound.
    const std::regex listening(R"(Modbus TCP on \[?[0-9a-f.:]+\]?:(\d+))");
    std::smatch match;
    const bool bound = eventually(
        [&] {
            const auto text = log();
            return std::regex_search(text, match, listening) || !running();
        },
        10s);
    const auto text = log();
    if (!bound || !std::regex_search(text, match, listening)) {
        ADD_FAILURE() << "ioportd did not start listening; its log:\n" << text;
        return;
    }
    port_ = static_cast<std::uint16_t>(std::stoi(match[1]));
    // The HTTP server starts after the Modbus one, before "ioportd 0.1.0 started: ..." (or the
    // daemon exits if it cannot).
    const std::regex started(R"(ioportd \S+ started: )");
    if (!eventually([&] { return std::regex_search(log(), started) || !running(); }, 10s))
        ADD_FAILURE() << "ioportd did not finish starting; its log:\n" << log();
    http_port_ = announced_http_port();
}

std::uint16_t GatewayProcess::announced_http_port(std::size_t from) const {
    static const std::regex announced(R"(HTTP on http://\[?[0-9a-f.:]+\]?:(\d+)/)");
    const auto text = log();
    if (from > text.size()) return 0;
    std::uint16_t port = 0;
    for (std::sregex_iterator
             it(text.begin() + static_cast<std::ptrdiff_t>(from), text.end(), announced),
         end;
         it != end; ++it)
        port = static_cast<std::uint16_t>(std::stoi((*it)[1]));
    return port;
}

GatewayProcess::~GatewayProcess() {
    if (pid_ > 0) stop(SIGTERM, 5s);
    if (::testing::Test::HasFailure()) std::cerr << "--- ioportd log ---\n" << log() << "---\n";
}

bool GatewayProcess::running() const {
    return pid_ > 0 && ::waitpid(pid_, nullptr, WNOHANG) == 0;
}

std::string GatewayProcess::log() const {
    std::ifstream in(log_path_);
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

bool GatewayProcess::wait_for_log(std::string_view text, std::chrono::milliseconds deadline,
                                  std::size_t from) const {
    return eventually(
        [&] {
            const auto all = log();
            return all.size() > from && all.find(text, from) != std::string::npos;
        },
        deadline);
}

void GatewayProcess::rewrite_config(const std::string& yaml) const {
    std::ofstream(config_path()) << yaml;
}

void GatewayProcess::signal(int signal) const {
    if (pid_ > 0) ::kill(pid_, signal);
}

int GatewayProcess::stop(int signal, std::chrono::milliseconds deadline) {
    if (pid_ <= 0) return -1;
    ::kill(pid_, signal);
    const int code = wait_exit(pid_, Clock::now() + deadline);
    if (code == -1) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
    }
    pid_ = -1;
    return code;
}

ModbusClient::ModbusClient(std::uint16_t port, int unit, const char* host)
    : context_(modbus_new_tcp(host, port)) {
    if (!context_) return;
    // A bound on a wait: a write queued behind others on a slow line answers late, not never.
    modbus_set_response_timeout(context_, static_cast<std::uint32_t>(3 * slowdown), 0);
    modbus_set_slave(context_, unit);
    connected_ = modbus_connect(context_) == 0;
}

ModbusClient::~ModbusClient() {
    if (!context_) return;
    modbus_close(context_);
    modbus_free(context_);
}

void ModbusClient::set_unit(int unit) {
    modbus_set_slave(context_, unit);
}

int ModbusClient::failure() const {
    return errno > MODBUS_ENOBASE && errno <= MODBUS_ENOBASE + 11 ? exception_code(errno) : -errno;
}

ModbusClient::Bits ModbusClient::read_coils(int address, int count) {
    std::vector<std::uint8_t> bits(static_cast<std::size_t>(std::max(count, 1)));
    if (modbus_read_bits(context_, address, count, bits.data()) < 0) return Unexpected(failure());
    return bits;
}

ModbusClient::Bits ModbusClient::read_discrete_inputs(int address, int count) {
    std::vector<std::uint8_t> bits(static_cast<std::size_t>(std::max(count, 1)));
    if (modbus_read_input_bits(context_, address, count, bits.data()) < 0)
        return Unexpected(failure());
    return bits;
}

ModbusClient::Registers ModbusClient::read_holding_registers(int address, int count) {
    std::vector<std::uint16_t> registers(static_cast<std::size_t>(std::max(count, 1)));
    if (modbus_read_registers(context_, address, count, registers.data()) < 0)
        return Unexpected(failure());
    return registers;
}

ModbusClient::Registers ModbusClient::read_input_registers(int address, int count) {
    std::vector<std::uint16_t> registers(static_cast<std::size_t>(std::max(count, 1)));
    if (modbus_read_input_registers(context_, address, count, registers.data()) < 0)
        return Unexpected(failure());
    return registers;
}

Expected<void, int> ModbusClient::write_coil(int address, bool on) {
    if (modbus_write_bit(context_, address, on ? 1 : 0) < 0) return Unexpected(failure());
    return {};
}

Expected<void, int> ModbusClient::write_register(int address, std::uint16_t value) {
    if (modbus_write_register(context_, address, value) < 0) return Unexpected(failure());
    return {};
}

Expected<void, int> ModbusClient::write_coils(int address,
                                              const std::vector<std::uint8_t>& values) {
    if (modbus_write_bits(context_, address, static_cast<int>(values.size()), values.data()) < 0)
        return Unexpected(failure());
    return {};
}

Expected<void, int> ModbusClient::write_registers(int address,
                                                  const std::vector<std::uint16_t>& values) {
    if (modbus_write_registers(context_, address, static_cast<int>(values.size()), values.data()) <
        0)
        return Unexpected(failure());
    return {};
}

}  // namespace ioport::test
