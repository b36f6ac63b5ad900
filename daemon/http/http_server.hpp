// The HTTP side's transport (gateway.md §5.4, §7.1): Boost.Beast on the daemon's io_context, one
// coroutine per connection, nothing blocking; plain or TLS-only, as the web configuration says.
// It decides who asks (the client certificate's CN, or Basic authentication), the route
// (http_route.hpp: the Host, the method and the path) and, for a write, that it is an operator's,
// as JSON, from the page's own origin; then asks the handler for the answer.
//
// Limits, so that a scanner, a slowloris or a flood never costs the Modbus side more than a few
// descriptors and microseconds, and one address never keeps another out (gateway.md §7.5): at
// most max_http_connections served at once and max_http_connections_per_address of one address
// (more are closed at accept); TLS handshakes in a budget of their own, which never takes the
// places of connections being served (max_http_handshakes, per address
// max_http_handshakes_per_address at once and a rate, a burst of http_handshake_burst then
// http_handshakes_per_second); a request line and headers of at most http_header_limit bytes,
// and a body only for a write, of at most max_write_body; the handshake and the whole request
// within http_request_timeout of the first byte (of the connection, for the first); a
// kept-alive connection closed after http_idle_timeout without a request; a response that the
// client does not take within http_request_timeout closes the connection. An address is the
// password limiter's (http_auth.hpp: an IPv6 one by http.ipv6_prefix).
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/base/listener.hpp"
#include "daemon/base/log.hpp"
#include "daemon/base/tls_server.hpp"
#include "daemon/http/http_auth.hpp"
#include "daemon/http/http_route.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

using namespace std::chrono_literals;

inline constexpr std::size_t max_http_connections = 64;
inline constexpr std::size_t max_http_connections_per_address = 8;
inline constexpr std::size_t max_http_handshakes = 16;
inline constexpr std::size_t max_http_handshakes_per_address = 4;
inline constexpr double http_handshake_burst = 8;
inline constexpr double http_handshakes_per_second = 4;
inline constexpr std::size_t http_header_limit = std::size_t{8} * 1024;
inline constexpr std::size_t max_write_body = 1024;
inline constexpr std::chrono::seconds http_request_timeout{10};
inline constexpr std::chrono::seconds http_idle_timeout{10};

// Who asks: their user, where there is one (a password checked, or a client certificate the
// handshake verified), and whether they may write (http.operators).
struct Caller {
    std::string user;  // "" when anonymous
    bool operator_ = false;
    asio::ip::address address;
};

struct HttpResponse {
    unsigned status = 200;
    std::string content_type = "text/plain; charset=utf-8";
    std::string body;
    std::vector<std::pair<std::string, std::string>> headers{};  // besides the server's own
};

// Connections refused or closed unserved, by reason (ioportd_http_connections_refused_total):
// owned by the output, so that a reload that moves the listener keeps counting.
struct HttpRefusals {
    std::uint64_t not_allowed = 0;          // not in http.allow
    std::uint64_t too_many = 0;             // max_http_connections served already
    std::uint64_t per_address = 0;          // max_http_connections_per_address of its address
    std::uint64_t too_many_handshakes = 0;  // the handshake budget, overall or of its address
    std::uint64_t tls_handshake = 0;        // a handshake that failed or timed out
};

// A routed request: the page, who asks, and a write's body (≤ max_write_body bytes).
struct HttpCall {
    Route route;
    Caller caller;
    std::string body;
};
using HttpHandler = std::function<asio::awaitable<HttpResponse>(HttpCall)>;

// A write's answer (gateway.md §7.1): {"result": "confirmed"}, or with an "error" text.
HttpResponse write_answer(unsigned status, std::string_view result, std::string_view error = {});

// The machine's host name (gethostname), or "" when it cannot be read.
std::string machine_host_name();

// The TLS context of the web configuration's tls_server_config (null without it).
Result<TlsContext> make_http_tls_context(const config::HttpSettings& settings);

// Owned through a shared_ptr: its coroutines keep it alive, so that a reload may drop it while
// they finish.
class HttpServer : public std::enable_shared_from_this<HttpServer> {
  public:
    // `host_name`: the machine's, which a request's Host may name besides http.server_names.
    // `tls`: make_http_tls_context(settings). `auth`: the users' passwords, shared by the servers
    // of one output.
    HttpServer(const asio::any_io_executor& executor, config::HttpSettings settings, TlsContext tls,
               std::shared_ptr<Authenticator> auth, std::string host_name, Log& log,
               HttpRefusals& refusals, HttpHandler handler);
    ~HttpServer();
    HttpServer(const HttpServer&) = delete;
    HttpServer& operator=(const HttpServer&) = delete;

    // Binds and listens; fails when the address is in use or not permitted.
    Result<> start();
    // Closes the listener and every connection.
    void stop();
    // A reload that keeps the address: the new allow list, which open connections must pass too,
    // the new server names, operators and headers. A change of tls_server_config closes every
    // connection: each was accepted under the old one, and its client reconnects under the new.
    void apply(config::HttpSettings next, TlsContext tls);

    const config::HttpSettings& settings() const { return settings_; }
    asio::ip::tcp::endpoint local_endpoint() const;
    std::size_t connections() const { return connections_.size(); }

  private:
    struct Connection;
    struct Exchange;
    // What one address holds: its connections, its handshakes, and its handshake tokens.
    struct Client {
        std::size_t connections = 0;  // handshaking ones included
        std::size_t handshakes = 0;
        double tokens = http_handshake_burst;
        std::chrono::steady_clock::time_point refilled{};
    };
    asio::awaitable<void> accept_loop(Acceptor acceptor);
    // Why a new connection from `peer` is refused: "" when it is taken.
    std::string refusal_of(const asio::ip::tcp::endpoint& peer, Client& client);
    Client& client(const ClientKey& key);
    void closed(Connection& connection);
    asio::awaitable<void> serve(std::shared_ptr<Connection> connection);
    template <class Stream>
    asio::awaitable<void> exchange(Connection& connection, Stream& stream);
    template <class Stream>
    asio::awaitable<HttpResponse> answer(Connection& connection, Stream& stream, Exchange& x);
    asio::awaitable<std::optional<HttpResponse>> authenticate(Connection& connection,
                                                              std::string_view authorization,
                                                              bool write, Caller& caller);
    template <class Stream>
    asio::awaitable<HttpResponse> read_write(Connection& connection, Stream& stream, Exchange& x,
                                             HttpCall& call);
    void log_refusal(const std::string& peer, std::string_view why);
    void set_names();

    asio::any_io_executor executor_;
    config::HttpSettings settings_;
    TlsContext tls_;
    std::shared_ptr<Authenticator> auth_;
    std::string host_name_;
    std::vector<std::string> names_;  // that a Host may give: host_name_ and server_names
    Log& log_;
    HttpHandler handler_;
    Acceptor acceptor_;
    asio::steady_timer accept_retry_;
    std::unordered_set<Connection*> connections_;
    std::unordered_map<ClientKey, Client, ClientKeyHash> clients_;
    std::size_t served_ = 0;      // connections past their handshake, or plain
    std::size_t handshakes_ = 0;  // connections in their TLS handshake
    HttpRefusals& refused_;
    LogLimiter refusals_;
};

}  // namespace ioport::daemon
