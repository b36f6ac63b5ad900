// Who asks the HTTP side (gateway.md §7.1): Basic authentication against the web
// configuration's bcrypt hashes, the failure limiter, and the credentials remembered once
// verified, so that a scrape a second costs no bcrypt. A bcrypt takes tens of milliseconds by
// design: it runs on the daemon's hashing thread, never on the loop, at most
// max_pending_verifications at once.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>

#include "daemon/log.hpp"
#include "daemon/worker_thread.hpp"
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

// Of each client address (an IPv6 one by its /64, which one machine usually has whole), the
// failures of the running minute: after max_failures the address is refused until the minute
// since its first failure is over. At most max_addresses are followed: when full, the one whose
// minute began first makes room.
class FailureLimiter {
  public:
    using Clock = std::chrono::steady_clock;
    static constexpr int max_failures = 5;
    static constexpr std::chrono::seconds window{60};
    static constexpr std::size_t max_addresses = 4096;

    // When the address may try again; nullopt when it may now.
    std::optional<Clock::time_point> refused_until(const asio::ip::address& address,
                                                   Clock::time_point now) const;
    void failed(const asio::ip::address& address, Clock::time_point now);
    std::size_t addresses() const { return failures_.size(); }

  private:
    using Key = std::array<unsigned char, 16>;
    struct Minute {
        Clock::time_point began;
        int failures = 0;
    };
    struct KeyHash {
        std::size_t operator()(const Key& key) const;
    };
    static Key key_of(const asio::ip::address& address);
    std::unordered_map<Key, Minute, KeyHash> failures_;
};

enum class AuthVerdict {
    authenticated,
    missing,  // no credentials: 401, not a failure (a browser's first request sends none)
    refused,  // wrong or malformed: 401, counted
    limited,  // the address failed too often: 429 until retry_at
    busy,     // max_pending_verifications are hashing: 503
};

struct AuthOutcome {
    AuthVerdict verdict = AuthVerdict::missing;
    std::string user{};  // of authenticated
    FailureLimiter::Clock::time_point retry_at{};
};

// Owned by the HTTP output, so that a reload that moves the listener keeps the limiter, the
// remembered credentials (while their hash stays) and the count.
class Authenticator {
  public:
    using Clock = FailureLimiter::Clock;
    static constexpr int max_pending_verifications = 8;

    Authenticator(const asio::any_io_executor& loop, WorkerThread& hashing, Log& log);

    // basic_auth_users (user: bcrypt hash); none: no authentication. A user whose hash changed is
    // verified anew.
    void set_users(std::map<std::string, std::string> users);
    bool required() const { return !users_.empty(); }
    // The request from `from` with this Authorization header ("" when it has none).
    asio::awaitable<AuthOutcome> check(asio::ip::address from, std::string authorization);
    // Requests refused for wrong credentials: ioportd_http_auth_failures_total.
    std::uint64_t failures() const { return failures_; }

  private:
    AuthOutcome refuse(const asio::ip::address& from, std::string_view user, Clock::time_point now);

    asio::any_io_executor loop_;
    WorkerThread& hashing_;
    Log& log_;
    std::map<std::string, std::string> users_;
    struct Verified {
        std::string hash;    // the bcrypt hash it was verified against
        std::string digest;  // SHA-256 of the password, never the password itself
    };
    std::map<std::string, Verified> verified_;  // one per user at most: bounded by the file
    FailureLimiter limiter_;
    LogLimiter logged_;
    int pending_ = 0;
    std::uint64_t failures_ = 0;
};

}  // namespace ioport::daemon
