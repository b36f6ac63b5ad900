// Who asks the HTTP side (gateway.md §7.1): Basic credentials, bcrypt through libxcrypt, the
// failure limiter, and the Authenticator that remembers what it verified. The hashes are
// htpasswd's (-nbBC 4: cost 4, so that the tests hash in a millisecond).
#include <array>
#include <chrono>
#include <future>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <openssl/evp.h>

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

// --- client_key -------------------------------------------------------------------------------

TEST(ClientKey, AnIpv6AddressIsItsPrefixAndAMappedIpv4Itself) {
    const auto key = [](const char* text, int prefix = 64) {
        return client_key(address(text), prefix);
    };
    EXPECT_EQ(key("2001:db8:1:2::1"), key("2001:db8:1:2:ffff::9"));
    EXPECT_NE(key("2001:db8:1:2::1"), key("2001:db8:1:3::1"));
    // A plant LAN's hosts share a /64: with 128 each is its own.
    EXPECT_NE(key("2001:db8:1:2::1", 128), key("2001:db8:1:2::2", 128));
    EXPECT_EQ(key("2001:db8:1:2::1", 128), key("2001:db8:1:2::1", 128));
    // A prefix that is not a whole number of bytes keeps its bits and no more.
    EXPECT_EQ(key("2001:db8:1:2:f000::", 68), key("2001:db8:1:2:ffff::", 68));
    EXPECT_NE(key("2001:db8:1:2:f000::", 68), key("2001:db8:1:2:e000::", 68));
    EXPECT_NE(key("2001:db8:1:2:f000::", 68), key("2001:db8:1:2:f000::", 72));
    EXPECT_EQ(key("::ffff:192.0.2.9"), key("192.0.2.9"));
    // An IPv4 address is not the IPv6 address whose first bytes are the same.
    EXPECT_NE(key("192.0.2.0"), key("c000:200::", 128));
    EXPECT_NE(key("0.0.0.0"), key("::", 128));
}

// --- CheckLimiter -----------------------------------------------------------------------------

using Clock = CheckLimiter::Clock;
const Clock::time_point t0{};

// One check from `a` at `at`, failed.
void failed_check(CheckLimiter& limiter, const asio::ip::address& a, Clock::time_point at) {
    limiter.finished(limiter.started(a, at), true, at);
}

TEST(CheckLimiter, FiveChecksInAnyMinuteRefuseThatAddressUntilTheOldestIsAMinuteOld) {
    CheckLimiter limiter;
    const auto a = address("192.0.2.1");
    for (int i = 0; i < 4; ++i)
        failed_check(limiter, a, t0 + i * 1s);
    EXPECT_FALSE(limiter.refused_until(a, t0 + 5s));
    failed_check(limiter, a, t0 + 10s);
    EXPECT_EQ(limiter.refused_until(a, t0 + 10s), t0 + 60s);
    EXPECT_EQ(limiter.refused_until(a, t0 + 59s), t0 + 60s);
    EXPECT_FALSE(limiter.refused_until(a, t0 + 60s));
    // Others are served meanwhile.
    EXPECT_FALSE(limiter.refused_until(address("192.0.2.2"), t0 + 10s));
    // A sliding minute, not one that starts anew: the next check at 60 s makes five within the
    // minute again (1 s … 60 s), so the address waits for its second oldest.
    failed_check(limiter, a, t0 + 60s);
    EXPECT_EQ(limiter.refused_until(a, t0 + 60s), t0 + 61s);
}

TEST(CheckLimiter, ACheckInFlightRefusesTheNextOfThatAddressUntilItsVerdict) {
    CheckLimiter limiter;
    const auto a = address("192.0.2.1");
    const auto key = limiter.started(a, t0);
    EXPECT_TRUE(limiter.in_flight(a));
    EXPECT_FALSE(limiter.refused_until(a, t0 + 1s));  // one check is not the limit
    EXPECT_FALSE(limiter.in_flight(address("192.0.2.2")));
    limiter.finished(key, false, t0 + 1s);
    EXPECT_FALSE(limiter.in_flight(a));
    EXPECT_FALSE(limiter.failing(a, t0 + 1s));
    // A reload that changes the prefix while a check runs: its end is still its address's.
    const auto v6 = address("2001:db8::1");
    const auto v6_key = limiter.started(v6, t0);
    limiter.set_ipv6_prefix(128);
    limiter.finished(v6_key, true, t0 + 1s);
    limiter.set_ipv6_prefix(64);
    EXPECT_FALSE(limiter.in_flight(v6));
    EXPECT_TRUE(limiter.failing(v6, t0 + 1s));
}

TEST(CheckLimiter, ChecksSpreadOverMinutesNeverAddUp) {
    CheckLimiter limiter;
    const auto a = address("192.0.2.1");
    for (int i = 0; i < 20; ++i) {
        EXPECT_FALSE(limiter.refused_until(a, t0 + i * 15s));
        failed_check(limiter, a, t0 + i * 15s);  // four a minute
    }
}

TEST(CheckLimiter, AFailureMakesTheAddressFailingForAMinute) {
    CheckLimiter limiter;
    const auto a = address("2001:db8::1");
    EXPECT_FALSE(limiter.failing(a, t0));
    failed_check(limiter, a, t0);
    EXPECT_TRUE(limiter.failing(a, t0 + 59s));
    EXPECT_TRUE(limiter.failing(address("2001:db8::2"), t0 + 59s));  // the same /64
    EXPECT_FALSE(limiter.failing(a, t0 + 60s));
    limiter.set_ipv6_prefix(128);
    EXPECT_FALSE(limiter.failing(address("2001:db8::2"), t0 + 1s));
}

TEST(CheckLimiter, ItFollowsABoundedNumberOfAddressesAndMakesRoomWithTheOldest) {
    CheckLimiter limiter;
    const auto nth = [](std::size_t i) {
        return asio::ip::address(asio::ip::address_v4(static_cast<std::uint32_t>(0x0A000000 + i)));
    };
    const auto attacker = address("198.51.100.7");
    for (int i = 0; i < 5; ++i)
        failed_check(limiter, attacker, t0 + 30s);
    // One with a check in flight is never made room with: its count would be lost.
    const auto waiting = address("198.51.100.8");
    limiter.started(waiting, t0);
    for (std::size_t i = 0; i < CheckLimiter::max_addresses + 1000; ++i)
        failed_check(limiter, nth(i), t0 + 31s);
    EXPECT_EQ(limiter.addresses(), CheckLimiter::max_addresses);
    EXPECT_TRUE(limiter.in_flight(waiting));
    // The newest are followed; the attacker, whose last check was the oldest, made room.
    for (int i = 0; i < 4; ++i)
        failed_check(limiter, nth(CheckLimiter::max_addresses + 999), t0 + 32s);
    EXPECT_TRUE(limiter.refused_until(nth(CheckLimiter::max_addresses + 999), t0 + 32s));
    EXPECT_FALSE(limiter.refused_until(attacker, t0 + 32s));
    // Minutes that are over make room before anyone else's.
    CheckLimiter other;
    for (std::size_t i = 0; i < CheckLimiter::max_addresses; ++i)
        failed_check(other, nth(i), t0);
    for (int i = 0; i < 5; ++i)
        failed_check(other, attacker, t0 + 61s);
    EXPECT_TRUE(other.refused_until(attacker, t0 + 61s));
    EXPECT_LE(other.addresses(), CheckLimiter::max_addresses);
}

// --- keyed_digest and decoy_hash --------------------------------------------------------------

TEST(KeyedDigest, ThePasswordUnderTheProcesssKeyTellsNothingWithoutIt) {
    DigestKey one{};
    DigestKey two{};
    two[0] = 1;
    EXPECT_EQ(keyed_digest(one, "secret"), keyed_digest(one, "secret"));
    EXPECT_NE(keyed_digest(one, "secret"), keyed_digest(one, "Secret"));
    EXPECT_NE(keyed_digest(one, "secret"), keyed_digest(two, "secret"));
    EXPECT_EQ(keyed_digest(one, "secret").size(), 32U);
    // Not the plain SHA-256 of the password, which a table of common passwords would reverse.
    std::array<unsigned char, 32> plain{};
    unsigned size = 0;
    EVP_Digest("secret", 6, plain.data(), &size, EVP_sha256(), nullptr);
    EXPECT_NE(keyed_digest(one, "secret"),
              std::string(reinterpret_cast<const char*>(plain.data()), plain.size()));
}

TEST(DecoyHash, TheCostMostUsersHaveSoAnUnknownUserCostsWhatAKnownOneDoes) {
    const auto cost = [](const std::map<std::string, std::string>& users) {
        const auto hash = decoy_hash(users);
        EXPECT_EQ(hash.size(), 60U);
        return hash.substr(0, 7);
    };
    EXPECT_EQ(cost({}), "$2b$10$");
    EXPECT_EQ(cost({{"alice", alice_hash}, {"bob", bob_hash}}), "$2b$04$");
    const std::string twelve = "$2y$12$" + std::string(alice_hash).substr(7);
    EXPECT_EQ(cost({{"alice", alice_hash}, {"bob", twelve}, {"carol", twelve}}), "$2b$12$");
    EXPECT_EQ(cost({{"alice", alice_hash}, {"bob", twelve}}), "$2b$12$");  // a tie: the higher
    // It is a hash libxcrypt takes, which no password matches.
    EXPECT_FALSE(bcrypt_matches(decoy_hash({{"alice", alice_hash}}), "secret"));
    EXPECT_FALSE(bcrypt_matches(decoy_hash({{"alice", alice_hash}}), ""));
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
    EXPECT_EQ(check(alice_wrong, "127.0.0.2")->verdict, AuthVerdict::refused);
    EXPECT_EQ(check("Basic bWFsbG9yeTpzZWNyZXQ=", "127.0.0.3")->verdict,  // mallory
              AuthVerdict::refused);
    EXPECT_EQ(check("Bearer x", "127.0.0.4")->verdict, AuthVerdict::refused);
    EXPECT_EQ(auth.failures(), 3U);
    // None at all is a browser's first request: asked for, not counted.
    EXPECT_EQ(check("", "127.0.0.5")->verdict, AuthVerdict::missing);
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
    // A check of the address in flight holds up no remembered password, and any other check.
    const auto meanwhile = check(alice_right, "127.0.0.1", 0ms);
    ASSERT_TRUE(meanwhile);
    EXPECT_EQ(meanwhile->verdict, AuthVerdict::authenticated);
    const auto other = check(bob_right, "127.0.0.1", 0ms);
    ASSERT_TRUE(other);
    EXPECT_EQ(other->verdict, AuthVerdict::limited);
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

TEST_F(AuthenticatorTest, FiveChecksLimitThatAddressEvenWithTheRightPasswordOthersAreServed) {
    for (int i = 0; i < CheckLimiter::max_checks; ++i)
        ASSERT_EQ(check(alice_wrong)->verdict, AuthVerdict::refused);
    const auto limited = check(alice_right);
    EXPECT_EQ(limited->verdict, AuthVerdict::limited);
    EXPECT_GT(limited->retry_at, Clock::now() + 50s);
    EXPECT_EQ(check("")->verdict, AuthVerdict::limited);
    EXPECT_EQ(check(alice_right, "127.0.0.2")->verdict, AuthVerdict::authenticated);
    EXPECT_EQ(auth.failures(), 5U);  // a limited request is not checked, so not counted
    EXPECT_EQ(auth.limited(), 2U);
}

// gateway.md §7.5: checks in flight count, so a burst from one address gets one check, not as
// many as run at once; and five within the minute in all.
TEST_F(AuthenticatorTest, ABurstFromOneAddressIsOneCheckAndTheMinuteStillHoldsFive) {
    auto release = hold_hashing();
    std::vector<std::optional<AuthOutcome>> burst(16);
    for (auto& outcome : burst)
        start(alice_wrong, "127.0.0.1", outcome);
    io.poll();
    const auto limited = std::ranges::count_if(
        burst, [](const auto& o) { return o && o->verdict == AuthVerdict::limited; });
    EXPECT_EQ(limited, 15);
    release.set_value();
    for (auto& outcome : burst)
        while (!outcome)
            io.run_one_for(10ms);
    EXPECT_EQ(auth.failures(), 1U);
    int refused = 0;
    for (int i = 0; i < 8; ++i)
        if (check(alice_wrong)->verdict == AuthVerdict::refused) ++refused;
    EXPECT_EQ(refused, 4);
    EXPECT_EQ(auth.failures(), 5U);
}

// gateway.md §7.5: addresses that have not failed go first, so that a user signs in while many
// addresses that failed keep the hashing thread busy; when the waiting room is full, such a user
// takes the place of the newest failing one, and nobody takes theirs.
TEST_F(AuthenticatorTest, AnAddressThatHasNotFailedGoesBeforeEveryFailingOne) {
    const auto attacker = [](std::size_t i) { return fmt::format("10.0.{}.{}", i / 200, i % 200); };
    const std::size_t attackers = Authenticator::max_waiting_checks + 1;  // one running, 32 waiting
    for (std::size_t i = 0; i <= attackers; ++i)
        ASSERT_EQ(check(alice_wrong, attacker(i).c_str())->verdict, AuthVerdict::refused);
    auto release = hold_hashing();
    std::vector<std::optional<AuthOutcome>> attacks(attackers);
    for (std::size_t i = 0; i < attackers; ++i)
        start(alice_wrong, attacker(i).c_str(), attacks[i]);
    io.poll();
    EXPECT_TRUE(std::ranges::none_of(attacks, [](const auto& o) { return o.has_value(); }));
    // The room is full: one more failing address is told to come back.
    const auto late_attack = check(alice_wrong, attacker(attackers).c_str(), 0ms);
    ASSERT_TRUE(late_attack);
    EXPECT_EQ(late_attack->verdict, AuthVerdict::busy);
    std::optional<AuthOutcome> user;
    start(bob_right, "192.0.2.10", user);
    io.poll();
    // The newest failing check made room for it.
    ASSERT_TRUE(attacks.back());
    EXPECT_EQ(attacks.back()->verdict, AuthVerdict::busy);
    // Served after the check already running, before the waiting failing ones.
    release.set_value();
    while (!user)
        io.run_one_for(10ms);
    EXPECT_EQ(user->verdict, AuthVerdict::authenticated);
    const auto finished_before = std::ranges::count_if(
        attacks, [](const auto& o) { return o && o->verdict == AuthVerdict::refused; });
    EXPECT_LE(finished_before, 1);
    for (auto& outcome : attacks)
        while (!outcome)
            io.run_one_for(10ms);
    EXPECT_EQ(auth.busy(), 2U);
}

}  // namespace
}  // namespace ioport::daemon
