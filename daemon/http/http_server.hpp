// The HTTP side's transport (gateway.md §5.4, §7.1): Boost.Beast on the daemon's io_context, one
// coroutine per connection, nothing blocking; plain or TLS-only, as the web configuration says.
// It decides who asks (the client certificate's CN, or Basic authentication), the route
// (http_route.hpp: the Host, the method and the path) and, for a write, that it is an operator's,
// as JSON, from the page's own origin; then asks the handler for the answer.
//
// Limits, so that a scanner, a slowloris or a flood never costs the Modbus side more than a few
// descriptors and microseconds: at most max_http_connections at once (more are closed at
// accept), TLS handshakes included; a request line and headers of at most http_header_limit
// bytes, and a body only for a write, of at most max_write_body; the handshake and the whole
// request within http_request_timeout of the first byte (of the connection, for the first); a
// kept-alive connection closed after http_idle_timeout without a request; a response that the
// client does not take within http_request_timeout closes the connection.
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <unordered_set>
#include <utility>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/http/http_auth.hpp"
#include "daemon/http/http_route.hpp"
#include "daemon/listener.hpp"
#include "daemon/log.hpp"
#include "daemon/tls_server.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

using namespace std::chrono_literals;

inline constexpr std::size_t max_http_connections = 64;
inline constexpr std::size_t http_header_limit = std::size_t{8} * 1024;
inline constexpr std::size_t max_write_body = 1024;
inline constexpr std::chrono::seconds http_request_timeout{10};
inline constexpr std::chrono::seconds http_idle_timeout{30};

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
               HttpHandler handler);
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
    asio::awaitable<void> accept_loop(Acceptor acceptor);
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
    LogLimiter refusals_;
};

}  // namespace ioport::daemon
