#include "daemon/http/http_server.hpp"

#include <unistd.h>

#include <array>
#include <climits>

#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include "protocol/error.hpp"

namespace ioport::daemon {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
using asio::redirect_error;
using asio::use_awaitable;
using asio::ip::tcp;

constexpr auto accept_error_pause = 100ms;

http::response<http::string_body> make_response(unsigned version, bool keep_alive,
                                                HttpResponse page) {
    http::response<http::string_body> response{static_cast<http::status>(page.status), version};
    response.set(http::field::server, "ioportd/" IOPORTD_VERSION);
    response.set(http::field::content_type, page.content_type);
    // Live data: a browser or proxy must ask again, never show an old copy.
    response.set(http::field::cache_control, "no-store");
    response.set("X-Content-Type-Options", "nosniff");
    // gateway.md §7.1: the status page keeps its script and style in files of its own for this.
    response.set("Content-Security-Policy", "default-src 'self'; frame-ancestors 'none'");
    response.set("Referrer-Policy", "no-referrer");
    if (page.status == 405) response.set(http::field::allow, "GET, HEAD");
    response.keep_alive(keep_alive);
    response.body() = std::move(page.body);  // a full /api/v1/trends is over a megabyte
    response.prepare_payload();
    return response;
}

std::string_view view(beast::string_view text) {
    return {text.data(), text.size()};
}

Request request_of(const http::request<http::empty_body>& request) {
    const auto host = request.find(http::field::host);
    return {view(request.method_string()), view(request.target()), request.version(),
            request.count(http::field::host), host == request.end() ? "" : view(host->value())};
}

}  // namespace

std::string machine_host_name() {
    std::array<char, HOST_NAME_MAX + 1> name{};
    if (::gethostname(name.data(), name.size() - 1) != 0) return {};
    return name.data();
}

struct HttpServer::Connection {
    Connection(tcp::socket socket, const tcp::endpoint& from)
        : stream(std::move(socket)), address(from.address()), peer(host_port(from)) {}
    beast::tcp_stream stream;
    asio::ip::address address;
    std::string peer;
};

HttpServer::HttpServer(const asio::any_io_executor& executor, config::HttpSettings settings,
                       std::string host_name, Log& log, HttpHandler handler)
    : executor_(executor),
      settings_(std::move(settings)),
      host_name_(std::move(host_name)),
      log_(log),
      handler_(std::move(handler)),
      accept_retry_(executor) {
    set_names();
}

void HttpServer::set_names() {
    names_ = settings_.server_names;
    if (!host_name_.empty()) names_.push_back(host_name_);
}

HttpServer::~HttpServer() = default;

Result<> HttpServer::start() {
    auto acceptor =
        listen_tcp(executor_, settings_.listen_host, settings_.listen_port, "http.listen");
    if (!acceptor) return Unexpected(acceptor.error());
    acceptor_ = std::move(*acceptor);
    log_.info({}, "HTTP on http://{}/ (status page, /metrics, /healthz)",
              host_port(local_endpoint()));
    asio::co_spawn(executor_, accept_loop(acceptor_), asio::detached);
    return {};
}

void HttpServer::stop() {
    boost::system::error_code ignored;
    if (acceptor_) acceptor_->close(ignored);
    accept_retry_.cancel();
    for (auto* connection : connections_)
        connection->stream.socket().close(ignored);
}

void HttpServer::apply(config::HttpSettings next) {
    settings_ = std::move(next);
    set_names();
    for (auto* connection : connections_) {
        if (allowed(settings_.allow, connection->address)) continue;
        boost::system::error_code ignored;
        connection->stream.socket().close(ignored);
    }
}

tcp::endpoint HttpServer::local_endpoint() const {
    boost::system::error_code ec;
    return acceptor_ ? acceptor_->local_endpoint(ec) : tcp::endpoint();
}

void HttpServer::log_refusal(const std::string& peer, std::string_view why) {
    // One line a minute for every refusal together: the peer's port makes each address new.
    const auto held = refusals_.admit("", std::chrono::steady_clock::now());
    if (!held) return;
    log_.warn({.client = peer}, "refused HTTP client {}: {} (logged once a minute){}", peer, why,
              held_back(*held));
}

asio::awaitable<void> HttpServer::accept_loop(Acceptor acceptor) {
    const auto self = shared_from_this();
    while (acceptor->is_open()) {
        tcp::socket socket(executor_);
        boost::system::error_code ec;
        co_await acceptor->async_accept(socket, redirect_error(use_awaitable, ec));
        if (!acceptor->is_open()) break;
        if (ec) {
            log_.warn({}, "accepting an HTTP client failed: {}", ec.message());
            accept_retry_.expires_after(accept_error_pause);
            co_await accept_retry_.async_wait(redirect_error(use_awaitable, ec));
            continue;
        }
        const auto peer = socket.remote_endpoint(ec);
        if (ec) continue;
        if (connections_.size() >= max_http_connections) {
            log_refusal(host_port(peer),
                        fmt::format("{} HTTP connections open", max_http_connections));
            continue;  // the socket closes as it goes out of scope
        }
        if (!allowed(settings_.allow, peer.address())) {
            log_refusal(host_port(peer), "not in http.allow");
            continue;
        }
        socket.set_option(tcp::no_delay(true), ec);
        auto connection = std::make_shared<Connection>(std::move(socket), peer);
        connections_.insert(connection.get());
        asio::co_spawn(executor_, serve(std::move(connection)), asio::detached);
    }
}

asio::awaitable<void> HttpServer::serve(std::shared_ptr<Connection> c) {
    const auto self = shared_from_this();
    beast::flat_buffer buffer(http_header_limit);
    bool first = true;
    for (;;) {
        boost::system::error_code ec;
        // A kept-alive connection may wait idle for its next request; a new one must send its
        // first request at once, whole, within the request timeout.
        if (!first && buffer.size() == 0) {
            c->stream.expires_after(http_idle_timeout);
            const auto n = co_await c->stream.async_read_some(buffer.prepare(http_header_limit),
                                                              redirect_error(use_awaitable, ec));
            if (ec) break;
            buffer.commit(n);
        }
        first = false;
        c->stream.expires_after(http_request_timeout);
        http::request_parser<http::empty_body> parser;
        parser.header_limit(http_header_limit);
        parser.body_limit(0);
        co_await http::async_read(c->stream, buffer, parser, redirect_error(use_awaitable, ec));
        if (ec == http::error::end_of_stream || ec == beast::error::timeout ||
            ec == asio::error::operation_aborted || ec == asio::error::connection_reset)
            break;
        HttpResponse page;
        bool keep_alive = false;
        unsigned version = 11;
        bool head = false;
        if (ec) {
            page = {ec == http::error::header_limit ? 431u
                    : ec == http::error::body_limit ? 413u
                                                    : 400u,
                    "text/plain; charset=utf-8", fmt::format("bad request: {}\n", ec.message())};
            // A request with a body (a form's POST, a PUT) is refused for its method or path,
            // as one without: 405 or 404 (gateway.md §5.4); 413 is left for a GET with a body.
            if (ec == http::error::body_limit && !parser.get().method_string().empty()) {
                version = parser.get().version();
                const auto routed = route(request_of(parser.get()), names_);
                if (!routed)
                    page = {routed.error().status, "text/plain; charset=utf-8",
                            routed.error().message + "\n"};
            }
        } else {
            const auto& request = parser.get();
            version = request.version();
            keep_alive = request.keep_alive();
            const auto routed = route(request_of(request), names_);
            if (routed) {
                head = routed->head;
                page = handler_(*routed);
            } else {
                if (routed.error().status == 421)
                    log_refusal(c->peer, fmt::format("Host {} is not this server's name (421): "
                                                     "if it is, add it to http.server_names",
                                                     printable(view(request[http::field::host]))));
                page = {routed.error().status, "text/plain; charset=utf-8",
                        routed.error().message + "\n"};
            }
        }
        auto response = make_response(version, keep_alive, std::move(page));
        c->stream.expires_after(http_request_timeout);
        if (head) {
            http::response_serializer<http::string_body> serializer(response);
            co_await http::async_write_header(c->stream, serializer,
                                              redirect_error(use_awaitable, ec));
        } else {
            co_await http::async_write(c->stream, response, redirect_error(use_awaitable, ec));
        }
        if (ec || !keep_alive) break;
    }
    boost::system::error_code ignored;
    c->stream.socket().shutdown(tcp::socket::shutdown_both, ignored);
    c->stream.socket().close(ignored);
    connections_.erase(c.get());
}

}  // namespace ioport::daemon
