// The real ioportd in its own process, and a real Modbus TCP client (libmodbus) to talk to it.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <modbus/modbus.h>

#include "tests/support/process.hpp"

namespace ioport::test {

// Polls `condition` every few milliseconds until it holds or `deadline` passes.
bool eventually(const std::function<bool()>& condition, std::chrono::milliseconds deadline = 5s);

// ioportd started on a configuration written to a temporary file; its stdout and stderr go to a
// log file, so a chatty daemon can never block on a full pipe. SIGTERM on destruction.
class GatewayProcess {
  public:
    // `yaml` may say "127.0.0.1:0" as listen address: the port the daemon bound is read from its
    // start-up log.
    // `environment`: NAME=VALUE entries added to the test's own environment.
    explicit GatewayProcess(const std::string& yaml, std::vector<std::string> extra = {},
                            const std::vector<std::string>& environment = {});
    ~GatewayProcess();
    GatewayProcess(const GatewayProcess&) = delete;
    GatewayProcess& operator=(const GatewayProcess&) = delete;

    std::uint16_t port() const { return port_; }
    // The HTTP port the daemon announced at start-up ("HTTP on http://127.0.0.1:PORT/ ..."); 0
    // when it has none (no http section, or `listen: ""`).
    std::uint16_t http_port() const { return http_port_; }
    // The HTTP port of the last such line in the log from `from` on (after a SIGHUP), or 0.
    std::uint16_t announced_http_port(std::size_t from = 0) const;
    pid_t pid() const { return pid_; }
    // The configuration file the daemon was started with; rewrite it before a SIGHUP.
    std::string config_path() const { return dir_ / "ioportd.yaml"; }
    void rewrite_config(const std::string& yaml) const;
    // Sends `signal` and leaves the daemon running.
    void signal(int signal) const;
    bool running() const;
    std::string log() const;
    // Waits for `text` to appear in the log (from `from` on, an offset into log()).
    bool wait_for_log(std::string_view text, std::chrono::milliseconds deadline = 5s,
                      std::size_t from = 0) const;
    // Sends `signal`; the exit status, or -1 if it did not exit within `deadline`.
    int stop(int signal = SIGTERM, std::chrono::milliseconds deadline = 5s);

  private:
    TempDir dir_;
    std::string log_path_;
    pid_t pid_ = -1;
    std::uint16_t port_ = 0;
    std::uint16_t http_port_ = 0;
};

// A libmodbus TCP client; every call returns the values or the Modbus exception code (1..11) /
// -errno of a transport failure.
class ModbusClient {
  public:
    ModbusClient(std::uint16_t port, int unit = 1, const char* host = "127.0.0.1");
    ~ModbusClient();
    ModbusClient(const ModbusClient&) = delete;
    ModbusClient& operator=(const ModbusClient&) = delete;

    bool connected() const { return connected_; }
    void set_unit(int unit);
    modbus_t* context() const { return context_; }

    using Registers = Expected<std::vector<std::uint16_t>, int>;
    using Bits = Expected<std::vector<std::uint8_t>, int>;
    Bits read_coils(int address, int count);
    Bits read_discrete_inputs(int address, int count);
    Registers read_holding_registers(int address, int count);
    Registers read_input_registers(int address, int count);
    Expected<void, int> write_coil(int address, bool on);
    Expected<void, int> write_register(int address, std::uint16_t value);
    Expected<void, int> write_coils(int address, const std::vector<std::uint8_t>& values);
    Expected<void, int> write_registers(int address, const std::vector<std::uint16_t>& values);

  private:
    int failure() const;
    modbus_t* context_ = nullptr;
    bool connected_ = false;
};

// The exception code a libmodbus call failed with, from its errno.
inline constexpr int exception_code(int modbus_errno) {
    return modbus_errno - MODBUS_ENOBASE;
}

}  // namespace ioport::test
