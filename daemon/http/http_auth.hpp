// Who asks the HTTP side (gateway.md §7.1): Basic authentication against the web
// configuration's bcrypt hashes, the failure limiter, and the credentials remembered once
// verified, so that a scrape a second costs no bcrypt. A bcrypt takes tens of milliseconds by
// design: it runs on the daemon's hashing thread, never on the loop, one at a time, each client
// address's in turn (gateway.md §7.5).
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>

#include "daemon/base/log.hpp"
#include "daemon/base/worker_thread.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

struct BasicCredentials {
    std::string user;
    std::string password;
    friend bool operator==(const BasicCredentials&, const BasicCredentials&) = default;
};

// An Authorization header's "Basic <base64 of user:password>" (RFC 7617; the scheme in any letter
// case); nullopt for another scheme, malformed base64, no ':', or a NUL in either part.
std::optional<BasicCredentials> parse_basic_credentials(std::string_view authorization);

// Whether `password` is the one `hash` was made of ($2a$, $2b$, $2y$: libxcrypt's bcrypt),
// compared in constant time. Blocking: tens of milliseconds at cost 10.
bool bcrypt_matches(const std::string& hash, std::string_view password);

// Where a request comes from, for the limits that count per address (gateway.md §7.5): an IPv4
// address (an IPv4-mapped IPv6 one as itself), or an IPv6 address by its first `ipv6_prefix` bits
// (64..128; a plant's hosts may share a /64, one machine usually has one whole).
using ClientKey = std::array<unsigned char, 17>;
ClientKey client_key(const asio::ip::address& address, int ipv6_prefix);
struct ClientKeyHash {
    std::size_t operator()(const ClientKey& key) const;
};

// Of each client address, the password checks of the last minute, whether one is in flight and
// whether one failed: at most max_checks within any minute, queued or running ones included, and
// one at a time. At most max_addresses are followed: when full, those with nothing in the last
// minute make room, then the one whose last check is oldest (never one with a check in flight).
class CheckLimiter {
  public:
    using Clock = std::chrono::steady_clock;
    static constexpr int max_checks = 5;
    static constexpr std::chrono::seconds window{60};
    static constexpr std::size_t max_addresses = 4096;
    // What a 429 for a check in flight says: it ends within a few bcrypt times.
    static constexpr std::chrono::seconds in_flight_retry{1};

    void set_ipv6_prefix(int bits) { ipv6_prefix_ = bits; }
    // When the address may be served again, having had max_checks checks within the minute;
    // nullopt when it may now.
    std::optional<Clock::time_point> refused_until(const asio::ip::address& address,
                                                   Clock::time_point now) const;
    // A check of this address is queued or running: it may start no other.
    bool in_flight(const asio::ip::address& address) const;
    // A check begins (queued): counted now, not when its verdict is known. Its key, for
    // finished(): a reload may change the prefix meanwhile.
    ClientKey started(const asio::ip::address& address, Clock::time_point now);
    // Its verdict: a failure puts the address behind the others until its minute is over.
    void finished(const ClientKey& key, bool failed, Clock::time_point now);
    // A check of this address failed within the last minute.
    bool failing(const asio::ip::address& address, Clock::time_point now) const;
    std::size_t addresses() const { return clients_.size(); }

  private:
    struct Client {
        std::array<Clock::time_point, max_checks> checks{};  // the newest max_checks, oldest first
        int count = 0;                                       // of checks[] in use
        bool in_flight = false;
        std::optional<Clock::time_point> failed{};
    };
    const Client* find(const asio::ip::address& address) const;
    void make_room(Clock::time_point now);
    std::unordered_map<ClientKey, Client, ClientKeyHash> clients_;
    int ipv6_prefix_ = config::default_ipv6_prefix;
};

enum class AuthVerdict {
    authenticated,
    missing,  // no credentials: 401, not a failure (a browser's first request sends none)
    refused,  // wrong or malformed: 401, counted
    limited,  // the address checked too often, or has a check in flight: 429 until retry_at
    busy,     // max_waiting_checks other addresses are waiting: 503
};

struct AuthOutcome {
    AuthVerdict verdict = AuthVerdict::missing;
    std::string user{};  // of authenticated
    CheckLimiter::Clock::time_point retry_at{};
};

// A digest of a password keyed with `key` (HMAC-SHA-256), as a verified password is remembered:
// without the key, which never leaves the process, it tells nothing about the password.
using DigestKey = std::array<unsigned char, 32>;
std::string keyed_digest(const DigestKey& key, std::string_view password);

// The hash an unknown user's password is checked against, so that refusing one costs what
// refusing a known user costs: of the cost most of `users` have (the highest of those tied), 10
// when there are none.
std::string decoy_hash(const std::map<std::string, std::string>& users);

// Owned by the HTTP output, so that a reload that moves the listener keeps the limiter, the
// remembered credentials (while their hash stays) and the count.
//
// One bcrypt at a time runs on the hashing thread; the checks waiting for it are served in two
// queues, addresses without a failure in the last minute first, each address at most once: an
// attacker with many addresses never keeps a user from signing in (gateway.md §7.5).
class Authenticator {
  public:
    using Clock = CheckLimiter::Clock;
    static constexpr std::size_t max_waiting_checks = 32;

    Authenticator(const asio::any_io_executor& loop, WorkerThread& hashing, Log& log);

    // basic_auth_users (user: bcrypt hash); none: no authentication. A user whose hash changed is
    // verified anew.
    void set_users(std::map<std::string, std::string> users);
    void set_ipv6_prefix(int bits) { limiter_.set_ipv6_prefix(bits); }
    bool required() const { return !users_.empty(); }
    // The request from `from` with this Authorization header ("" when it has none).
    asio::awaitable<AuthOutcome> check(asio::ip::address from, std::string authorization);
    // Requests refused for wrong credentials: ioportd_http_auth_failures_total.
    std::uint64_t failures() const { return failures_; }
    // Requests refused unchecked: ioportd_http_auth_refused_total{reason}.
    std::uint64_t limited() const { return limited_; }
    std::uint64_t busy() const { return busy_; }

  private:
    struct Waiter;
    AuthOutcome refuse(const asio::ip::address& from, std::string_view user, Clock::time_point now);
    // Waits for the hashing thread's turn; false when a better placed check took the place.
    asio::awaitable<bool> take_turn(bool failing);
    void next_turn();

    asio::any_io_executor loop_;
    WorkerThread& hashing_;
    Log& log_;
    std::map<std::string, std::string> users_;
    std::string decoy_;
    DigestKey key_{};
    struct Verified {
        std::string hash;    // the bcrypt hash it was verified against
        std::string digest;  // keyed_digest of the password, never the password itself
    };
    std::map<std::string, Verified> verified_;  // one per user at most: bounded by the file
    CheckLimiter limiter_;
    LogLimiter logged_;
    std::deque<std::shared_ptr<Waiter>> clean_;    // addresses without a recent failure
    std::deque<std::shared_ptr<Waiter>> failing_;  // the others
    bool hashing_busy_ = false;
    std::uint64_t failures_ = 0;
    std::uint64_t limited_ = 0;
    std::uint64_t busy_ = 0;
};

}  // namespace ioport::daemon
