#include "daemon/base/log.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <string>

#include "protocol/error.hpp"

namespace ioport::daemon {
namespace {

TEST(JournalEntry, CarriesPriorityIdentifierAndTheFieldsThatAreSet) {
    const auto entry = journal_entry(LogLevel::warn, {"hub0", 1, "dom16 0", {}},
                                     "link hub0: dom16 0 offline: no answer");
    const std::vector<std::string> expected{"MESSAGE=link hub0: dom16 0 offline: no answer",
                                            "PRIORITY=4",
                                            "SYSLOG_IDENTIFIER=ioportd",
                                            "LINK=hub0",
                                            "UNIT=1",
                                            "MODULE=dom16 0"};
    EXPECT_EQ(entry, expected);
}

// Modbus/TCP Security (gateway.md §5.6): who connected, by certificate and role; ROLE is there
// when empty too, so that "no role" can be searched for (journalctl ROLE=).
TEST(JournalEntry, ATlsClientHasItsSubjectAndRole) {
    const TlsIdentity operator_1{"O=Plant,CN=operator-1", "operator"};
    const auto entry =
        journal_entry(LogLevel::info, {.client = "10.0.0.5:50123", .tls = &operator_1}, "x");
    const std::vector<std::string> expected{"MESSAGE=x",
                                            "PRIORITY=6",
                                            "SYSLOG_IDENTIFIER=ioportd",
                                            "CLIENT=10.0.0.5:50123",
                                            "TLS_SUBJECT=O=Plant,CN=operator-1",
                                            "ROLE=operator"};
    EXPECT_EQ(entry, expected);
    const TlsIdentity nobody{"CN=norole-1", ""};
    EXPECT_EQ(journal_entry(LogLevel::info, {.tls = &nobody}, "x").back(), "ROLE=");
}

TEST(JournalEntry, LevelsMapToSyslogPriorities) {
    const auto priority = [](LogLevel level) { return journal_entry(level, {}, "x").at(1); };
    EXPECT_EQ(priority(LogLevel::debug), "PRIORITY=7");
    EXPECT_EQ(priority(LogLevel::info), "PRIORITY=6");
    EXPECT_EQ(priority(LogLevel::warn), "PRIORITY=4");
    EXPECT_EQ(priority(LogLevel::err), "PRIORITY=3");
    EXPECT_EQ(priority(LogLevel::critical), "PRIORITY=2");
    EXPECT_EQ(journal_entry(LogLevel::info, {.client = "10.0.0.5:502"}, "x").back(),
              "CLIENT=10.0.0.5:502");
    EXPECT_EQ(journal_entry(LogLevel::info, {}, "x").size(), 3U);
    EXPECT_EQ(journal_entry(LogLevel::warn, {.comm_loss = true}, "x").back(), "COMM_LOSS=1");
}

TEST(JournalStream, MatchesOnlyItsOwnDeviceAndInode) {
    EXPECT_TRUE(is_journal_stream("8:123456", 8, 123456));
    EXPECT_FALSE(is_journal_stream("8:123456", 8, 123457));
    EXPECT_FALSE(is_journal_stream("9:123456", 8, 123456));
    EXPECT_FALSE(is_journal_stream(nullptr, 8, 123456));
    EXPECT_FALSE(is_journal_stream("", 8, 123456));
    EXPECT_FALSE(is_journal_stream("garbage", 8, 123456));
}

TEST(LogLevels, FilterByLevel) {
    Log log(Log::Target::standard_error, LogLevel::warn);
    EXPECT_FALSE(log.enabled(LogLevel::info));
    EXPECT_TRUE(log.enabled(LogLevel::warn));
    EXPECT_TRUE(log.enabled(LogLevel::critical));
    log.set_level(LogLevel::off);
    EXPECT_FALSE(log.enabled(LogLevel::critical));
}

// --- Lines a network peer can cause (issue 23) -------------------------------------------------

TEST(LogLimiter, OneLineAMinutePerKeyThenHowManyWereHeldBack) {
    LogLimiter limiter;
    const LogLimiter::Clock::time_point t0{std::chrono::hours(1)};
    EXPECT_EQ(limiter.admit("hub0.dom16.0 metric", t0), 0u);
    for (int i = 1; i <= 1000; ++i)
        EXPECT_EQ(limiter.admit("hub0.dom16.0 metric", t0 + std::chrono::milliseconds(i)),
                  std::nullopt);
    // another reason has its own minute
    EXPECT_EQ(limiter.admit("hub0.dom16.0 read_only", t0 + std::chrono::seconds(1)), 0u);
    EXPECT_EQ(limiter.admit("hub0.dom16.0 metric", t0 + std::chrono::seconds(59)), std::nullopt);
    EXPECT_EQ(limiter.admit("hub0.dom16.0 metric", t0 + std::chrono::seconds(60)), 1001u);
    EXPECT_EQ(limiter.admit("hub0.dom16.0 metric", t0 + std::chrono::seconds(121)), 0u);
    EXPECT_EQ(held_back(0), "");
    EXPECT_EQ(held_back(1001), " (1001 more since the last line)");
}

TEST(LogLimiter, KeysMadeUpByAPeerCostBoundedMemory) {
    LogLimiter limiter(std::chrono::seconds(60), 4);
    const LogLimiter::Clock::time_point t0{std::chrono::hours(1)};
    for (int i = 0; i < 4; ++i)
        EXPECT_EQ(limiter.admit(std::to_string(i), t0), 0u);
    EXPECT_EQ(limiter.admit("0", t0), std::nullopt);
    EXPECT_EQ(limiter.admit("4", t0), 0u);  // a fifth: the memory starts again
    EXPECT_EQ(limiter.admit("0", t0), 0u);
}

// The one escaping of network-borne text for log lines (protocol/error.hpp).
TEST(Printable, NetworkTextCannotForgeALine) {
    EXPECT_EQ(printable("out/0\n2026-12-02 16:00:00.000 info fake line"),
              "out/0\\n2026-12-02 16:00:00.000 info fake line");
    EXPECT_EQ(printable("a\rb\\c\x1b[2J\x7f"), "a\\rb\\\\c\\x1B[2J\\x7F");
    EXPECT_EQ(printable(std::string_view("nul\0x", 5)), "nul\\x00x");
    // UTF-8 is escaped byte by byte: no line or paragraph separator, no direction override
    EXPECT_EQ(printable("\u2028\u202e"), "\\xE2\\x80\\xA8\\xE2\\x80\\xAE");
    EXPECT_EQ(printable("printable ASCII ~ stays"), "printable ASCII ~ stays");
}

TEST(Printable, ALongTextIsCut) {
    EXPECT_EQ(printable(std::string(100, 'x'), 4), "xxxx...");
    EXPECT_EQ(printable("\n\n\n\n\n", 2), "\\n\\n...");
    EXPECT_EQ(printable("abcd", 4), "abcd");
}

}  // namespace
}  // namespace ioport::daemon
