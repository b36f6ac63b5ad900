#include "daemon/base/log.hpp"

#include <sys/uio.h>
#include <systemd/sd-journal.h>

#include <cstdio>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

namespace ioport::daemon {
namespace {

constexpr int notice_priority = 5;

// syslog(3)'s priorities, which the journal uses.
int priority(LogLevel level) {
    switch (level) {
        case LogLevel::trace:
        case LogLevel::debug:
            return 7;
        case LogLevel::info:
            return 6;
        case LogLevel::warn:
            return 4;
        case LogLevel::err:
            return 3;
        case LogLevel::critical:
        case LogLevel::off:
        case LogLevel::n_levels:
            break;
    }
    return 2;
}

}  // namespace

std::vector<std::string> journal_entry(LogLevel level, const LogFields& fields,
                                       std::string_view message) {
    std::vector<std::string> entry{
        fmt::format("MESSAGE={}", message),
        fmt::format("PRIORITY={}", fields.audit ? notice_priority : priority(level)),
        "SYSLOG_IDENTIFIER=ioportd"};
    if (!fields.link.empty()) entry.push_back(fmt::format("LINK={}", fields.link));
    if (fields.unit >= 0) entry.push_back(fmt::format("UNIT={}", fields.unit));
    if (!fields.module.empty()) entry.push_back(fmt::format("MODULE={}", fields.module));
    if (!fields.client.empty()) entry.push_back(fmt::format("CLIENT={}", fields.client));
    if (fields.comm_loss) entry.emplace_back("COMM_LOSS=1");
    if (const auto* tls = fields.tls) {
        entry.push_back(fmt::format("TLS_SUBJECT={}", tls->subject));
        entry.push_back(fmt::format("ROLE={}", tls->role));
    }
    if (const auto* audit = fields.audit) {
        entry.push_back(fmt::format("FUNCTION={}", audit->function));
        entry.push_back(fmt::format("ADDRESS={}", audit->address));
        entry.push_back(fmt::format("VALUE={}", audit->value));
        entry.push_back(fmt::format("RESULT={}", audit->result));
        entry.push_back(fmt::format("LATENCY_US={}", audit->latency_us));
    }
    return entry;
}

bool is_journal_stream(const char* journal_stream, dev_t device, ino_t inode) {
    if (journal_stream == nullptr) return false;
    unsigned long long stream_device = 0;
    unsigned long long stream_inode = 0;
    // NOLINTNEXTLINE(cert-err34-c): a malformed value simply does not match
    if (std::sscanf(journal_stream, "%llu:%llu", &stream_device, &stream_inode) != 2) return false;
    return stream_device == device && stream_inode == inode;
}

std::optional<std::uint64_t> LogLimiter::admit(std::string_view key, Clock::time_point now) {
    const auto found = seen_.find(std::string(key));
    if (found != seen_.end()) {
        auto& seen = found->second;
        if (now - seen.logged < interval_) {
            ++seen.held;
            return std::nullopt;
        }
        return std::exchange(seen, Seen{now, 0}).held;
    }
    if (seen_.size() >= keys_) seen_.clear();
    seen_.emplace(std::string(key), Seen{now, 0});
    return 0;
}

std::string held_back(std::uint64_t held) {
    if (held == 0) return {};
    return fmt::format(" ({} more since the last line)", held);
}

Log::Log(Target target, LogLevel level)
    : target_(target),
      level_(level),
      stderr_(std::make_shared<spdlog::logger>(
          "ioportd", std::make_shared<spdlog::sinks::stderr_color_sink_st>())) {
    stderr_->set_pattern("%Y-%m-%d %H:%M:%S.%e %^%l%$ %v");
    stderr_->set_level(spdlog::level::trace);  // filtered here, by level_
}

Log::~Log() = default;

void Log::write(LogLevel level, const LogFields& fields, std::string_view message) {
    if (target_ == Target::journal) {
        const auto entry = journal_entry(level, fields, message);
        std::vector<iovec> vector;
        vector.reserve(entry.size());
        for (const auto& field : entry)
            vector.push_back({const_cast<char*>(field.data()), field.size()});
        // Should the journal be gone (journald restarting), the line still goes somewhere.
        if (sd_journal_sendv(vector.data(), static_cast<int>(vector.size())) >= 0) return;
    }
    write_stderr(level, message);
}

void Log::write_stderr(LogLevel level, std::string_view message) {
    stderr_->log(level, "{}", message);
}

}  // namespace ioport::daemon
