// Who asks the HTTP side (gateway.md §7.1): Basic credentials, bcrypt through libxcrypt, the
// failure limiter, and the Authenticator that remembers what it verified. The hashes are
// htpasswd's (-nbBC 4: cost 4, so that the tests hash in a millisecond).
#include <chrono>
#include <future>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "daemon/http/http_auth.hpp"

namespace ioport::daemon {
namespace {

using namespace std::chrono_literals;

constexpr const char* alice_hash = "$2y$04$sGO5GKf0dpvOcga0RM2/Ye037FPBgYeYLDPwBpx1VY2vk.4fZO5JW";
constexpr const char* bob_hash = "$2y$04$1s2aLdRMlI7Gqq6ylxcPCO64dAl2XMc57vBrzvw9vP6ye8xvNoH7i";
// Basic base64("alice:secret"), base64("alice:wrong"), base64("bob:hunter2").
constexpr const char* alice_right = "Basic YWxpY2U6c2VjcmV0";
constexpr const char* alice_wrong = "Basic YWxpY2U6d3Jvbmc=";
constexpr const char* bob_right = "Basic Ym9iOmh1bnRlcjI=";

asio::ip::address address(const char* text) {
    return asio::ip::make_address(text);
}

// --- parse_basic_credentials ------------------------------------------------------------------

TEST(BasicCredentials, TheSchemeInAnyCaseThenBase64OfUserColonPassword) {
    EXPECT_EQ(parse_basic_credentials(alice_right), (BasicCredentials{"alice", "secret"}));
    EXPECT_EQ(parse_basic_credentials("basic YWxpY2U6c2VjcmV0"),
              (BasicCredentials{"alice", "secret"}));
    EXPECT_EQ(parse_basic_credentials("BASIC   YWxpY2U6c2VjcmV0  "),
              (BasicCredentials{"alice", "secret"}));
    // One '=' and two of padding; the password may hold colons (RFC 7617: the first one splits).
    EXPECT_EQ(parse_basic_credentials(alice_wrong), (BasicCredentials{"alice", "wrong"}));
    EXPECT_EQ(parse_basic_credentials("Basic YTpi"), (BasicCredentials{"a", "b"}));
    EXPECT_EQ(parse_basic_credentials("Basic YTpiOmM="), (BasicCredentials{"a", "b:c"}));
    EXPECT_EQ(parse_basic_credentials("Basic Og=="), (BasicCredentials{"", ""}));
}

TEST(BasicCredentials, AnythingElseIsNone) {
    for (const auto header :
         {"", "Basic", "Basic ", "Bearer YWxpY2U6c2VjcmV0", "Digest username=alice",
          "BasicYWxpY2U6c2VjcmV0", "Basic YWxpY2U6c2VjcmV0=", "Basic YWxpY2U6c2VjcmV",
          "Basic YWxp Y2U6c2VjcmV0", "Basic YWxpY2U!c2VjcmV0", "Basic YWxpY2U=",  // no colon
          "Basic YTpiAA==",                                                       // a NUL
          "Basic ====", "Basic =YWx"}) {
        SCOPED_TRACE(header);
        EXPECT_FALSE(parse_basic_credentials(header));
    }
}

// --- bcrypt_matches ---------------------------------------------------------------------------

TEST(Bcrypt, TheRightPasswordOfEachPrefixMatchesAndNothingElse) {
    EXPECT_TRUE(bcrypt_matches(alice_hash, "secret"));
    EXPECT_FALSE(bcrypt_matches(alice_hash, "Secret"));
    EXPECT_FALSE(bcrypt_matches(alice_hash, ""));
    EXPECT_FALSE(bcrypt_matches(alice_hash, std::string_view("secret\0x", 8)));
    EXPECT_TRUE(bcrypt_matches(bob_hash, "hunter2"));
    // $2a$ and $2b$ are the same hash under another name, for a password of ASCII.
    std::string b = alice_hash;
    b[2] = 'b';
    EXPECT_TRUE(bcrypt_matches(b, "secret"));
    b[2] = 'a';
    EXPECT_TRUE(bcrypt_matches(b, "secret"));
    // Not a hash libxcrypt takes: never a match, whatever the password.
    EXPECT_FALSE(bcrypt_matches("", ""));
    EXPECT_FALSE(bcrypt_matches("secret", "secret"));
    EXPECT_FALSE(bcrypt_matches("$2y$04$short", "secret"));
}

// --- FailureLimiter ---------------------------------------------------------------------------

using Clock = FailureLimiter::Clock;
const Clock::time_point t0{};

TEST(FailureLimiter, FiveFailuresInAMinuteRefuseThatAddressUntilTheMinuteIsOver) {
    FailureLimiter limiter;
    const auto a = address("192.0.2.1");
    for (int i = 0; i < 4; ++i)
        limiter.failed(a, t0 + i * 1s);
    EXPECT_FALSE(limiter.refused_until(a, t0 + 5s));
    limiter.failed(a, t0 + 10s);
    EXPECT_EQ(limiter.refused_until(a, t0 + 10s), t0 + 60s);
    EXPECT_EQ(limiter.refused_until(a, t0 + 59s), t0 + 60s);
    EXPECT_FALSE(limiter.refused_until(a, t0 + 60s));
    // Others are served meanwhile.
    EXPECT_FALSE(limiter.refused_until(address("192.0.2.2"), t0 + 10s));
    // A new minute begins with its first failure.
    limiter.failed(a, t0 + 61s);
    EXPECT_FALSE(limiter.refused_until(a, t0 + 61s));
}

TEST(FailureLimiter, FailuresSpreadOverMinutesNeverAddUp) {
    FailureLimiter limiter;
    const auto a = address("192.0.2.1");
    for (int i = 0; i < 20; ++i)
        limiter.failed(a, t0 + i * 15s);  // four a minute
    EXPECT_FALSE(limiter.refused_until(a, t0 + 300s));
}

TEST(FailureLimiter, AnIpv6AddressCountsByItsSlash64AndAMappedIpv4AsItself) {
    FailureLimiter limiter;
    for (int i = 1; i <= 5; ++i)
        limiter.failed(address(fmt::format("2001:db8:1:2::{:x}", i).c_str()), t0);
    EXPECT_TRUE(limiter.refused_until(address("2001:db8:1:2:ffff::1"), t0));
    EXPECT_FALSE(limiter.refused_until(address("2001:db8:1:3::1"), t0));
    EXPECT_EQ(limiter.addresses(), 1U);
    for (int i = 0; i < 5; ++i)
        limiter.failed(address("::ffff:192.0.2.9"), t0);
    EXPECT_TRUE(limiter.refused_until(address("192.0.2.9"), t0));
    // An IPv4 address is not the IPv6 /64 whose first bytes are the same.
    EXPECT_FALSE(limiter.refused_until(address("c000:209::"), t0));
}

TEST(FailureLimiter, ItFollowsABoundedNumberOfAddressesAndMakesRoomWithTheOldest) {
    FailureLimiter limiter;
    const auto nth = [](std::size_t i) {
        return asio::ip::address(asio::ip::address_v4(static_cast<std::uint32_t>(0x0A000000 + i)));
    };
    const auto attacker = address("198.51.100.7");
    for (int i = 0; i < 5; ++i)
        limiter.failed(attacker, t0 + 30s);
    for (std::size_t i = 0; i < FailureLimiter::max_addresses + 1000; ++i)
        limiter.failed(nth(i), t0 + 31s);
    EXPECT_EQ(limiter.addresses(), FailureLimiter::max_addresses);
    // The newest are followed; the one made room for first was the oldest: the attacker, whose
    // minute began first. (Flooding the table frees an address: it gains what the flood cost.)
    for (int i = 0; i < 4; ++i)
        limiter.failed(nth(FailureLimiter::max_addresses + 999), t0 + 32s);
    EXPECT_TRUE(limiter.refused_until(nth(FailureLimiter::max_addresses + 999), t0 + 32s));
    EXPECT_FALSE(limiter.refused_until(attacker, t0 + 32s));
    // Minutes that are over make room before anyone else's.
    FailureLimiter other;
    for (std::size_t i = 0; i < FailureLimiter::max_addresses; ++i)
        other.failed(nth(i), t0);
    for (int i = 0; i < 5; ++i)
        other.failed(attacker, t0 + 61s);
    EXPECT_TRUE(other.refused_until(attacker, t0 + 61s));
    EXPECT_LE(other.addresses(), FailureLimiter::max_addresses);
}

// --- Authenticator ----------------------------------------------------------------------------

// An Authenticator on a loop of the test's, with a hashing thread that the test can hold up.
class AuthenticatorTest : public ::testing::Test {
  protected:
    AuthenticatorTest() { auth.set_users({{"alice", alice_hash}, {"bob", bob_hash}}); }

    // Starts a check and runs what is ready on the loop; then, until it completes or
    // `deadline` passes, what comes.
    std::optional<AuthOutcome> check(const char* header, const char* from = "127.0.0.1",
                                     std::chrono::milliseconds deadline = 10s) {
        std::optional<AuthOutcome> outcome;
        start(header, from, outcome);
        io.poll();
        const auto until = std::chrono::steady_clock::now() + deadline;
        while (!outcome && std::chrono::steady_clock::now() < until)
            io.run_one_for(10ms);
        return outcome;
    }
    void start(const char* header, const char* from, std::optional<AuthOutcome>& outcome) {
        asio::co_spawn(io, auth.check(address(from), header),
                       [&outcome](const std::exception_ptr&, AuthOutcome o) { outcome = o; });
    }
    // The hashing thread takes nothing more until the returned promise is set.
    std::promise<void> hold_hashing() {
        std::promise<void> release;
        hashing.post([held = release.get_future().share()] { held.wait(); });
        return release;
    }

    asio::io_context io;
    asio::executor_work_guard<asio::io_context::executor_type> work{io.get_executor()};
    WorkerThread hashing;
    Log log{Log::Target::standard_error, config::LogLevel::off};
    Authenticator auth{io.get_executor(), hashing, log};
};

TEST_F(AuthenticatorTest, TheRightPasswordIsTheUserAndAnythingElseAFailureCounted) {
    const auto right = check(alice_right);
    ASSERT_TRUE(right);
    EXPECT_EQ(right->verdict, AuthVerdict::authenticated);
    EXPECT_EQ(right->user, "alice");
    EXPECT_EQ(check(bob_right)->user, "bob");
    EXPECT_EQ(auth.failures(), 0U);
    EXPECT_EQ(check(alice_wrong)->verdict, AuthVerdict::refused);
    EXPECT_EQ(check("Basic bWFsbG9yeTpzZWNyZXQ=")->verdict, AuthVerdict::refused);  // mallory
    EXPECT_EQ(check("Bearer x")->verdict, AuthVerdict::refused);
    EXPECT_EQ(auth.failures(), 3U);
    // None at all is a browser's first request: asked for, not counted.
    EXPECT_EQ(check("")->verdict, AuthVerdict::missing);
    EXPECT_EQ(auth.failures(), 3U);
}

TEST_F(AuthenticatorTest, AVerifiedPasswordIsRememberedAndAnotherOneIsHashed) {
    ASSERT_EQ(check(alice_right)->verdict, AuthVerdict::authenticated);
    auto release = hold_hashing();
    // Answered on the loop alone, the hashing thread held up: no bcrypt.
    const auto again = check(alice_right, "127.0.0.1", 0ms);
    ASSERT_TRUE(again) << "a remembered password went to the hashing thread";
    EXPECT_EQ(again->user, "alice");
    std::optional<AuthOutcome> wrong;
    start(alice_wrong, "127.0.0.1", wrong);
    io.poll();
    EXPECT_FALSE(wrong) << "a wrong password must be hashed, never compared with the remembered";
    release.set_value();
    while (!wrong)
        io.run_one_for(10ms);
    EXPECT_EQ(wrong->verdict, AuthVerdict::refused);
}

TEST_F(AuthenticatorTest, AReloadThatChangesAUsersHashForgetsWhatWasVerified) {
    ASSERT_EQ(check(alice_right)->verdict, AuthVerdict::authenticated);
    auth.set_users({{"alice", bob_hash}});  // alice's password is now hunter2
    EXPECT_EQ(check(alice_right)->verdict, AuthVerdict::refused);
    EXPECT_EQ(check("Basic YWxpY2U6aHVudGVyMg==")->user, "alice");
    auth.set_users({{"carol", bob_hash}});
    EXPECT_EQ(check("Basic YWxpY2U6aHVudGVyMg==")->verdict, AuthVerdict::refused);
}

TEST_F(AuthenticatorTest, FiveFailuresLimitThatAddressEvenWithTheRightPasswordOthersAreServed) {
    for (int i = 0; i < FailureLimiter::max_failures; ++i)
        ASSERT_EQ(check(alice_wrong)->verdict, AuthVerdict::refused);
    const auto limited = check(alice_right);
    EXPECT_EQ(limited->verdict, AuthVerdict::limited);
    EXPECT_GT(limited->retry_at, Clock::now() + 50s);
    EXPECT_EQ(check("")->verdict, AuthVerdict::limited);
    EXPECT_EQ(check(alice_right, "127.0.0.2")->verdict, AuthVerdict::authenticated);
    EXPECT_EQ(auth.failures(), 5U);  // a limited request is not checked, so not counted
}

TEST_F(AuthenticatorTest, AtMostEightVerificationsWaitForTheHashingThread) {
    auto release = hold_hashing();
    std::vector<std::optional<AuthOutcome>> waiting(Authenticator::max_pending_verifications);
    for (auto& outcome : waiting)
        start(bob_right, "127.0.0.1", outcome);
    io.poll();
    const auto busy = check(alice_right, "127.0.0.1", 0ms);
    ASSERT_TRUE(busy);
    EXPECT_EQ(busy->verdict, AuthVerdict::busy);
    release.set_value();
    for (auto& outcome : waiting) {
        while (!outcome)
            io.run_one_for(10ms);
        EXPECT_EQ(outcome->verdict, AuthVerdict::authenticated);
    }
}

}  // namespace
}  // namespace ioport::daemon
