#include "daemon/http/http_auth.hpp"

#include <crypt.h>

#include <algorithm>
#include <cstring>
#include <memory>

#include <fmt/format.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>

#include "protocol/hex.hpp"

namespace ioport::daemon {
namespace {

// Checked against when the user is unknown, so that an unknown user takes as long to refuse as a
// wrong password: the answer's time tells no one which users exist. Cost 10, as htpasswd -nBC 10.
constexpr std::string_view unknown_user_hash =
    "$2b$10$d7enEMjJTTVxEJCW4OtbheqMos5ISD.cKh7EOO3YKSbYPpclm3qVa";

std::string sha256(std::string_view text) {
    std::array<unsigned char, EVP_MAX_MD_SIZE> digest{};
    unsigned size = 0;
    EVP_Digest(text.data(), text.size(), digest.data(), &size, EVP_sha256(), nullptr);
    return {reinterpret_cast<const char*>(digest.data()), size};
}

bool same(std::string_view a, std::string_view b) {
    return a.size() == b.size() && CRYPTO_memcmp(a.data(), b.data(), a.size()) == 0;
}

}  // namespace

std::optional<BasicCredentials> parse_basic_credentials(std::string_view authorization) {
    constexpr std::string_view scheme = "basic ";
    if (authorization.size() < scheme.size() ||
        !std::ranges::equal(authorization.substr(0, scheme.size()), scheme, {},
                            [](char c) { return c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c; }))
        return std::nullopt;
    auto encoded = authorization.substr(scheme.size());
    while (!encoded.empty() && encoded.front() == ' ')
        encoded.remove_prefix(1);
    while (!encoded.empty() && encoded.back() == ' ')
        encoded.remove_suffix(1);
    if (encoded.empty() || encoded.size() % 4 != 0) return std::nullopt;
    // EVP_DecodeBlock decodes whole groups of four, padding included as zero bytes, and skips
    // no character: what it refuses is not base64.
    std::string decoded(encoded.size() / 4 * 3, '\0');
    const int length = EVP_DecodeBlock(reinterpret_cast<unsigned char*>(decoded.data()),
                                       reinterpret_cast<const unsigned char*>(encoded.data()),
                                       static_cast<int>(encoded.size()));
    if (length < 0) return std::nullopt;
    const auto padding =
        static_cast<std::size_t>(std::ranges::count(encoded.substr(encoded.size() - 2), '='));
    decoded.resize(static_cast<std::size_t>(length) - padding);
    const auto colon = decoded.find(':');
    if (colon == std::string::npos || decoded.find('\0') != std::string::npos) return std::nullopt;
    return BasicCredentials{decoded.substr(0, colon), decoded.substr(colon + 1)};
}

bool bcrypt_matches(const std::string& hash, std::string_view password) {
    if (password.find('\0') != std::string_view::npos) return false;
    // Large (tens of KiB) and per call: libxcrypt keeps its work there, so that two calls never
    // share a buffer.
    const auto work = std::make_unique<crypt_data>();
    const char* made = crypt_r(std::string(password).c_str(), hash.c_str(), work.get());
    // libxcrypt answers a string starting with '*' for a hash it cannot take.
    if (made == nullptr || made[0] == '*') return false;
    return same(made, hash);
}

FailureLimiter::Key FailureLimiter::key_of(const asio::ip::address& address) {
    Key key{};
    if (address.is_v4()) {
        const auto bytes = address.to_v4().to_bytes();
        std::ranges::copy(bytes, key.begin());
        return key;
    }
    const auto v6 = address.to_v6();
    if (v6.is_v4_mapped()) return key_of(asio::ip::make_address_v4(asio::ip::v4_mapped, v6));
    const auto bytes = v6.to_bytes();
    std::copy_n(bytes.begin(), 8, key.begin() + 8);  // the /64, apart from every IPv4 key
    key[0] = 6;
    return key;
}

std::size_t FailureLimiter::KeyHash::operator()(const Key& key) const {
    return std::hash<std::string_view>{}(
        std::string_view(reinterpret_cast<const char*>(key.data()), key.size()));
}

std::optional<FailureLimiter::Clock::time_point> FailureLimiter::refused_until(
    const asio::ip::address& address, Clock::time_point now) const {
    const auto it = failures_.find(key_of(address));
    if (it == failures_.end() || it->second.failures < max_failures) return std::nullopt;
    const auto until = it->second.began + window;
    if (now >= until) return std::nullopt;
    return until;
}

void FailureLimiter::failed(const asio::ip::address& address, Clock::time_point now) {
    const auto key = key_of(address);
    auto it = failures_.find(key);
    if (it == failures_.end()) {
        if (failures_.size() >= max_addresses) {
            std::erase_if(failures_,
                          [&](const auto& entry) { return now - entry.second.began >= window; });
            if (failures_.size() >= max_addresses)
                failures_.erase(std::ranges::min_element(
                    failures_, {}, [](const auto& entry) { return entry.second.began; }));
        }
        it = failures_.emplace(key, Minute{now, 0}).first;
    }
    if (now - it->second.began >= window) it->second = {now, 0};
    ++it->second.failures;
}

Authenticator::Authenticator(const asio::any_io_executor& loop, WorkerThread& hashing, Log& log)
    : loop_(loop), hashing_(hashing), log_(log) {}

void Authenticator::set_users(std::map<std::string, std::string> users) {
    users_ = std::move(users);
    std::erase_if(verified_, [&](const auto& entry) {
        const auto user = users_.find(entry.first);
        return user == users_.end() || user->second != entry.second.hash;
    });
}

asio::awaitable<AuthOutcome> Authenticator::check(asio::ip::address from,
                                                  std::string authorization) {
    const auto now = Clock::now();
    if (const auto until = limiter_.refused_until(from, now))
        co_return AuthOutcome{AuthVerdict::limited, {}, *until};
    if (authorization.empty()) co_return AuthOutcome{AuthVerdict::missing};
    auto credentials = parse_basic_credentials(authorization);
    if (!credentials) co_return refuse(from, "", now);
    const auto user = users_.find(credentials->user);
    const auto digest = sha256(credentials->password);
    if (user != users_.end())
        if (const auto seen = verified_.find(user->first);
            seen != verified_.end() && same(seen->second.digest, digest))
            co_return AuthOutcome{AuthVerdict::authenticated, user->first};
    if (pending_ >= max_pending_verifications) co_return AuthOutcome{AuthVerdict::busy};
    const std::string hash = user != users_.end() ? user->second : std::string(unknown_user_hash);
    ++pending_;
    // Made apart from the co_await: g++ 12 destroys a lambda's captures twice when the lambda is
    // a temporary of the co_await's full expression.
    auto verification = hashing_.run(loop_, [hash, password = std::move(credentials->password)] {
        return bcrypt_matches(hash, password);
    });
    const bool matches = co_await std::move(verification);
    --pending_;
    // A reload may have changed the users meanwhile: what counts is the hash still there.
    const auto now_user = users_.find(credentials->user);
    if (!matches || now_user == users_.end() || now_user->second != hash)
        co_return refuse(from, credentials->user, Clock::now());
    verified_[now_user->first] = {hash, digest};
    co_return AuthOutcome{AuthVerdict::authenticated, now_user->first};
}

AuthOutcome Authenticator::refuse(const asio::ip::address& from, std::string_view user,
                                  Clock::time_point now) {
    ++failures_;
    limiter_.failed(from, now);
    const auto address = from.to_string();
    if (const auto held = logged_.admit(address, now))
        log_.warn(
            {.client = address},
            "HTTP: authentication failed for {} from {} (logged once a minute per "
            "address){}",
            user.empty() ? "malformed credentials" : fmt::format("user '{}'", printable(user)),
            address, held_back(*held));
    return {AuthVerdict::refused};
}

}  // namespace ioport::daemon
