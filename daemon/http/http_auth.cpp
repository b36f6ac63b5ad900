#include "daemon/http/http_auth.hpp"

#include <crypt.h>

#include <algorithm>
#include <cctype>
#include <cstring>
#include <memory>
#include <stdexcept>

#include <fmt/format.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>
#include <openssl/rand.h>

#include "protocol/hex.hpp"

namespace ioport::daemon {
namespace {

// Checked against when the user is unknown, so that an unknown user takes as long to refuse as a
// wrong password: the answer's time tells no one which users exist. decoy_hash() sets its cost
// to the users'.
constexpr std::string_view unknown_user_hash =
    "$2b$10$d7enEMjJTTVxEJCW4OtbheqMos5ISD.cKh7EOO3YKSbYPpclm3qVa";

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

ClientKey client_key(const asio::ip::address& address, int ipv6_prefix) {
    ClientKey key{};
    if (address.is_v4()) {
        const auto bytes = address.to_v4().to_bytes();
        std::ranges::copy(bytes, key.begin());
        return key;
    }
    const auto v6 = address.to_v6();
    if (v6.is_v4_mapped())
        return client_key(asio::ip::make_address_v4(asio::ip::v4_mapped, v6), ipv6_prefix);
    // The prefix's bits, the rest zero, and the prefix's length: apart from every IPv4 key (whose
    // last byte is 0) and from another prefix length's.
    const auto bytes = v6.to_bytes();
    const auto bits = static_cast<std::size_t>(std::clamp(ipv6_prefix, 0, 128));
    std::copy_n(bytes.begin(), bits / 8, key.begin());
    if (bits % 8 != 0)
        key[bits / 8] = static_cast<unsigned char>(bytes[bits / 8] & (0xFF00 >> (bits % 8)));
    key[16] = static_cast<unsigned char>(bits + 1);
    return key;
}

std::size_t ClientKeyHash::operator()(const ClientKey& key) const {
    return std::hash<std::string_view>{}(
        std::string_view(reinterpret_cast<const char*>(key.data()), key.size()));
}

const CheckLimiter::Client* CheckLimiter::find(const asio::ip::address& address) const {
    const auto it = clients_.find(client_key(address, ipv6_prefix_));
    return it == clients_.end() ? nullptr : &it->second;
}

std::optional<CheckLimiter::Clock::time_point> CheckLimiter::refused_until(
    const asio::ip::address& address, Clock::time_point now) const {
    const auto* client = find(address);
    if (client == nullptr || client->count < max_checks) return std::nullopt;
    const auto until = client->checks.front() + window;  // the oldest of the last five
    if (now >= until) return std::nullopt;
    return until;
}

bool CheckLimiter::in_flight(const asio::ip::address& address) const {
    const auto* client = find(address);
    return client != nullptr && client->in_flight;
}

void CheckLimiter::make_room(Clock::time_point now) {
    std::erase_if(clients_, [&](const auto& entry) {
        const auto& c = entry.second;
        return !c.in_flight && (c.count == 0 || now - c.checks[c.count - 1] >= window);
    });
    if (clients_.size() < max_addresses) return;
    auto oldest = clients_.end();
    for (auto it = clients_.begin(); it != clients_.end(); ++it)
        if (!it->second.in_flight &&
            (oldest == clients_.end() || it->second.checks[it->second.count - 1] <
                                             oldest->second.checks[oldest->second.count - 1]))
            oldest = it;
    if (oldest != clients_.end()) clients_.erase(oldest);
}

ClientKey CheckLimiter::started(const asio::ip::address& address, Clock::time_point now) {
    const auto key = client_key(address, ipv6_prefix_);
    auto it = clients_.find(key);
    if (it == clients_.end()) {
        if (clients_.size() >= max_addresses) make_room(now);
        it = clients_.emplace(key, Client{}).first;
    }
    auto& client = it->second;
    if (client.count == max_checks) {
        std::shift_left(client.checks.begin(), client.checks.end(), 1);
        --client.count;
    }
    client.checks[static_cast<std::size_t>(client.count++)] = now;
    client.in_flight = true;
    return key;
}

void CheckLimiter::finished(const ClientKey& key, bool failed, Clock::time_point now) {
    const auto it = clients_.find(key);
    if (it == clients_.end()) return;
    it->second.in_flight = false;
    if (failed) it->second.failed = now;
}

bool CheckLimiter::failing(const asio::ip::address& address, Clock::time_point now) const {
    const auto* client = find(address);
    return client != nullptr && client->failed && now - *client->failed < window;
}

std::string keyed_digest(const DigestKey& key, std::string_view password) {
    std::array<unsigned char, EVP_MAX_MD_SIZE> digest{};
    unsigned size = 0;
    HMAC(EVP_sha256(), key.data(), static_cast<int>(key.size()),
         reinterpret_cast<const unsigned char*>(password.data()), password.size(), digest.data(),
         &size);
    return {reinterpret_cast<const char*>(digest.data()), size};
}

std::string decoy_hash(const std::map<std::string, std::string>& users) {
    std::map<int, int> users_of_cost;
    for (const auto& [name, hash] : users)
        if (hash.size() > 6 && std::isdigit(static_cast<unsigned char>(hash[4])) != 0 &&
            std::isdigit(static_cast<unsigned char>(hash[5])) != 0)
            ++users_of_cost[(hash[4] - '0') * 10 + (hash[5] - '0')];
    int cost = 10;
    int most = 0;
    for (const auto& [c, count] : users_of_cost)
        if (count >= most) {  // ascending: a tie goes to the higher cost
            cost = c;
            most = count;
        }
    // The decoy's salt and checksum are any valid ones: what costs is the cost.
    auto hash = std::string(unknown_user_hash);
    hash[4] = static_cast<char>('0' + cost / 10);
    hash[5] = static_cast<char>('0' + cost % 10);
    return hash;
}

struct Authenticator::Waiter {
    explicit Waiter(const asio::any_io_executor& loop) : turn(loop, Clock::time_point::max()) {}
    asio::steady_timer turn;  // cancelled when it is this check's turn, or it lost its place
    bool taken = false;       // its turn came
};

Authenticator::Authenticator(const asio::any_io_executor& loop, WorkerThread& hashing, Log& log)
    : loop_(loop), hashing_(hashing), log_(log), decoy_(decoy_hash({})) {
    // Drawn once per process: a digest remembered here means nothing anywhere else.
    if (RAND_bytes(key_.data(), static_cast<int>(key_.size())) != 1)
        throw std::runtime_error("OpenSSL's RAND_bytes failed: no key for remembered passwords");
}

void Authenticator::set_users(std::map<std::string, std::string> users) {
    users_ = std::move(users);
    decoy_ = decoy_hash(users_);
    std::erase_if(verified_, [&](const auto& entry) {
        const auto user = users_.find(entry.first);
        return user == users_.end() || user->second != entry.second.hash;
    });
}

asio::awaitable<bool> Authenticator::take_turn(bool failing) {
    auto& queue = failing ? failing_ : clean_;
    if (clean_.size() + failing_.size() >= max_waiting_checks) {
        // A clean address takes the place of the newest failing one; nobody takes a clean one's.
        if (failing || failing_.empty()) co_return false;
        failing_.back()->turn.cancel();
        failing_.pop_back();
    }
    const auto waiter = std::make_shared<Waiter>(loop_);
    queue.push_back(waiter);
    next_turn();
    if (!waiter->taken) {
        boost::system::error_code ec;
        co_await waiter->turn.async_wait(asio::redirect_error(asio::use_awaitable, ec));
    }
    co_return waiter->taken;
}

void Authenticator::next_turn() {
    if (hashing_busy_) return;
    auto& queue = clean_.empty() ? failing_ : clean_;
    if (queue.empty()) return;
    hashing_busy_ = true;
    queue.front()->taken = true;
    queue.front()->turn.cancel();
    queue.pop_front();
}

asio::awaitable<AuthOutcome> Authenticator::check(asio::ip::address from,
                                                  std::string authorization) {
    const auto now = Clock::now();
    if (const auto until = limiter_.refused_until(from, now)) {
        ++limited_;
        co_return AuthOutcome{AuthVerdict::limited, {}, *until};
    }
    if (authorization.empty()) co_return AuthOutcome{AuthVerdict::missing};
    auto credentials = parse_basic_credentials(authorization);
    const auto user = credentials ? users_.find(credentials->user) : users_.end();
    const auto digest = credentials ? keyed_digest(key_, credentials->password) : std::string();
    // A password verified before is no check, so a check of this address in flight (another
    // user's at the same workstation, say) holds it up no more than the limit does.
    if (user != users_.end())
        if (const auto seen = verified_.find(user->first);
            seen != verified_.end() && same(seen->second.digest, digest))
            co_return AuthOutcome{AuthVerdict::authenticated, user->first};
    if (limiter_.in_flight(from)) {
        ++limited_;
        co_return AuthOutcome{AuthVerdict::limited, {}, now + CheckLimiter::in_flight_retry};
    }
    if (!credentials) {
        limiter_.finished(limiter_.started(from, now), true, now);
        co_return refuse(from, "", now);
    }
    const std::string hash = user != users_.end() ? user->second : decoy_;
    const auto key = limiter_.started(from, now);
    // Made apart from the co_await: g++ 12 destroys a temporary of the co_await's full
    // expression twice.
    auto turn = take_turn(limiter_.failing(from, now));
    if (!co_await std::move(turn)) {
        limiter_.finished(key, false, Clock::now());
        ++busy_;
        co_return AuthOutcome{AuthVerdict::busy};
    }
    auto verification = hashing_.run(loop_, [hash, password = std::move(credentials->password)] {
        return bcrypt_matches(hash, password);
    });
    const bool matches = co_await std::move(verification);
    hashing_busy_ = false;
    next_turn();
    // A reload may have changed the users meanwhile: what counts is the hash still there.
    const auto now_user = users_.find(credentials->user);
    const bool authenticated = matches && now_user != users_.end() && now_user->second == hash;
    limiter_.finished(key, !authenticated, Clock::now());
    if (!authenticated) co_return refuse(from, credentials->user, Clock::now());
    verified_[now_user->first] = {hash, digest};
    co_return AuthOutcome{AuthVerdict::authenticated, now_user->first};
}

AuthOutcome Authenticator::refuse(const asio::ip::address& from, std::string_view user,
                                  Clock::time_point now) {
    ++failures_;
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
