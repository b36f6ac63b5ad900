// The HTTP side's transport (gateway.md §5.4): Boost.Beast on the daemon's io_context, one
// coroutine per connection, nothing blocking. It decides the route (http_route.hpp: the Host, the
// method and the path) and asks the handler for the page; it never changes an output, as only
// GET and HEAD are routed.
//
// Limits, so that a scanner, a slowloris or a flood never costs the Modbus side more than a few
// descriptors and microseconds: at most max_http_connections at once (more are closed at
// accept); a request line and headers of at most http_header_limit bytes and no body; the whole
// request within http_request_timeout of its first byte (of the connection, for the first);
// a kept-alive connection closed after http_idle_timeout without a request; a response that the
// client does not take within http_request_timeout closes the connection.
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <unordered_set>

#include "config/gateway_config.hpp"
#include "daemon/http/http_route.hpp"
#include "daemon/listener.hpp"
#include "daemon/log.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

using namespace std::chrono_literals;

inline constexpr std::size_t max_http_connections = 64;
inline constexpr std::size_t http_header_limit = std::size_t{8} * 1024;
inline constexpr std::chrono::seconds http_request_timeout{10};
inline constexpr std::chrono::seconds http_idle_timeout{30};

struct HttpResponse {
    unsigned status = 200;
    std::string content_type = "text/plain; charset=utf-8";
    std::string body;
};
using HttpHandler = std::function<HttpResponse(const Route& route)>;

// The machine's host name (gethostname), or "" when it cannot be read.
std::string machine_host_name();

// Owned through a shared_ptr: its coroutines keep it alive, so that a reload may drop it while
// they finish.
class HttpServer : public std::enable_shared_from_this<HttpServer> {
  public:
    // `host_name`: the machine's, which a request's Host may name besides http.server_names.
    HttpServer(const asio::any_io_executor& executor, config::HttpSettings settings,
               std::string host_name, Log& log, HttpHandler handler);
    ~HttpServer();
    HttpServer(const HttpServer&) = delete;
    HttpServer& operator=(const HttpServer&) = delete;

    // Binds and listens; fails when the address is in use or not permitted.
    Result<> start();
    // Closes the listener and every connection.
    void stop();
    // A reload that keeps the address: the new allow list, which open connections must pass too,
    // and the new server names.
    void apply(config::HttpSettings next);

    const config::HttpSettings& settings() const { return settings_; }
    asio::ip::tcp::endpoint local_endpoint() const;
    std::size_t connections() const { return connections_.size(); }

  private:
    struct Connection;
    asio::awaitable<void> accept_loop(Acceptor acceptor);
    asio::awaitable<void> serve(std::shared_ptr<Connection> connection);
    void log_refusal(const std::string& peer, std::string_view why);
    void set_names();

    asio::any_io_executor executor_;
    config::HttpSettings settings_;
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
