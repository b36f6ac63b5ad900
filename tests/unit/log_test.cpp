#include "daemon/log.hpp"

#include <gtest/gtest.h>

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

}  // namespace
}  // namespace ioport::daemon
