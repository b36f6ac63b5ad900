// ioportd's log: one line per event worth an operator's attention, to stderr with timestamps or
// to the systemd journal with fields (journalctl -u ioportd LINK=hub0 MODULE="dom16 0").
// An object made in main() and handed to whoever logs: no global logger.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "config/gateway_config.hpp"

namespace spdlog {
class logger;
}

namespace ioport::daemon {

using config::LogLevel;

// A write that reached a link: the audit trail (gateway.md §5.4, issue 16).
struct WriteAudit {
    std::string_view function{};  // the Modbus function code, "6"; "DCMD"; "safe" (comm loss)
    std::string_view address{};   // the first register or coil, "0"; the metric; the module
    std::string_view value{};     // what was written: "1", "0x00FF", "1 0 1", "10 20 30"
    std::string_view result{};    // confirmed, error_ack, no_answer, link_down
    long long latency_us = 0;     // request received → outcome known
};

// Who a Modbus/TCP Security client is (gateway.md §5.6): its certificate's subject and its role
// ("" for none).
struct TlsIdentity {
    std::string_view subject{};
    std::string_view role{};
};

// What a line is about. Empty fields are left out of the journal entry.
struct LogFields {
    std::string_view link{};    // a link's name
    int unit = -1;              // its Modbus unit id; -1: none
    std::string_view module{};  // "dom16 0", "ID-2"
    std::string_view client{};  // a Modbus client, "10.0.0.5:50123"
    bool comm_loss = false;     // COMM_LOSS=1: outputs put in their safe state (gateway.md §5.3)
    // FUNCTION, ADDRESS, VALUE, RESULT, LATENCY_US; a line with them is a notice (PRIORITY=5).
    const WriteAudit* audit = nullptr;
    const TlsIdentity* tls = nullptr;  // TLS_SUBJECT, ROLE (also when empty)
};

// The journal entry of one line, as KEY=value strings: MESSAGE, PRIORITY (syslog's numbers),
// SYSLOG_IDENTIFIER and the fields that are set.
std::vector<std::string> journal_entry(LogLevel level, const LogFields& fields,
                                       std::string_view message);

// systemd sets JOURNAL_STREAM to "device:inode" of the journal stream it connected to stdout and
// stderr; stderr goes to the journal when its own device and inode are those.
bool is_journal_stream(const char* journal_stream, dev_t device, ino_t inode);

// The one policy for lines a network peer can cause at any rate (refused clients, refused
// commands): a line per key (an address and a reason, a kind of refusal) at most once a minute,
// and that line tells how many were held back since the previous one: a port scanner, an HMI
// retrying every second or a host flooding DCMDs must not flood the log. Remembers at
// most `keys` keys; more, and it starts again from none, so that a peer making up keys costs
// memory of `keys` entries at most. The time is the caller's: pure, and tested without waiting.
class LogLimiter {
  public:
    using Clock = std::chrono::steady_clock;
    static constexpr std::chrono::seconds default_interval{60};

    explicit LogLimiter(Clock::duration interval = default_interval, std::size_t keys = 1024)
        : interval_(interval), keys_(keys) {}

    // nullopt: hold this line back; else it goes out, and this many were held back before it.
    std::optional<std::uint64_t> admit(std::string_view key, Clock::time_point now);

  private:
    struct Seen {
        Clock::time_point logged;
        std::uint64_t held = 0;
    };
    Clock::duration interval_;
    std::size_t keys_;
    std::unordered_map<std::string, Seen> seen_;
};

// " (3 more since the last line)" after a line that LogLimiter let out; "" when none were held.
std::string held_back(std::uint64_t held);

class Log {
  public:
    enum class Target { standard_error, journal };

    Log(Target target, LogLevel level);
    ~Log();
    Log(const Log&) = delete;
    Log& operator=(const Log&) = delete;

    Target target() const { return target_; }
    void set_level(LogLevel level) { level_ = level; }
    bool enabled(LogLevel level) const { return level_ != LogLevel::off && level >= level_; }

    template <class... Args>
    void debug(const LogFields& fields, fmt::format_string<Args...> format, Args&&... args) {
        emit(LogLevel::debug, fields, format, std::forward<Args>(args)...);
    }
    template <class... Args>
    void info(const LogFields& fields, fmt::format_string<Args...> format, Args&&... args) {
        emit(LogLevel::info, fields, format, std::forward<Args>(args)...);
    }
    // A write's audit line: info on stderr, "notice" (5) in the journal.
    template <class... Args>
    void notice(const LogFields& fields, fmt::format_string<Args...> format, Args&&... args) {
        emit(LogLevel::info, fields, format, std::forward<Args>(args)...);
    }
    template <class... Args>
    void warn(const LogFields& fields, fmt::format_string<Args...> format, Args&&... args) {
        emit(LogLevel::warn, fields, format, std::forward<Args>(args)...);
    }
    template <class... Args>
    void error(const LogFields& fields, fmt::format_string<Args...> format, Args&&... args) {
        emit(LogLevel::err, fields, format, std::forward<Args>(args)...);
    }
    template <class... Args>
    void critical(const LogFields& fields, fmt::format_string<Args...> format, Args&&... args) {
        emit(LogLevel::critical, fields, format, std::forward<Args>(args)...);
    }

    void write(LogLevel level, const LogFields& fields, std::string_view message);

  private:
    template <class... Args>
    void emit(LogLevel level, const LogFields& fields, fmt::format_string<Args...> format,
              Args&&... args) {
        if (enabled(level)) write(level, fields, fmt::format(format, std::forward<Args>(args)...));
    }
    void write_stderr(LogLevel level, std::string_view message);

    Target target_;
    LogLevel level_;
    std::shared_ptr<spdlog::logger> stderr_;
};

}  // namespace ioport::daemon
