#include "daemon/http/http_server.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <climits>
#include <sstream>
#include <variant>

#include <openssl/ssl.h>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>

#include "protocol/error.hpp"
#include "protocol/json.hpp"

namespace ioport::daemon {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
using asio::redirect_error;
using asio::use_awaitable;
using asio::ip::tcp;
using PlainStream = beast::tcp_stream;
using SecureStream = beast::ssl_stream<beast::tcp_stream>;

constexpr auto accept_error_pause = 100ms;

// Every response's, before the web configuration's headers (which may replace them): no
// sniffing of a type, no address of this server in another site's logs, no script or frame but
// this server's own.
constexpr std::array<std::pair<std::string_view, std::string_view>, 3> security_headers{{
    {"X-Content-Type-Options", "nosniff"},
    {"Referrer-Policy", "no-referrer"},
    {"Content-Security-Policy", "default-src 'self'; frame-ancestors 'none'"},
}};

std::string_view view(beast::string_view text) {
    return {text.data(), text.size()};
}

HttpResponse text(unsigned status, std::string body) {
    return {status, std::string(text_plain), std::move(body) + "\n"};
}

// A refusal as a page's (text) or a write's (JSON) answer.
HttpResponse refusal(bool write, unsigned status, std::string_view result, std::string message) {
    return write ? write_answer(status, result, message) : text(status, std::move(message));
}

// The media type of a Content-Type, parameters aside, compared without regard to case.
bool json_content(std::string_view content_type) {
    auto type = content_type.substr(0, content_type.find(';'));
    while (!type.empty() && (type.back() == ' ' || type.back() == '\t'))
        type.remove_suffix(1);
    constexpr std::string_view json = "application/json";
    return type.size() == json.size() && std::ranges::equal(type, json, {}, [](char c) {
               return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c;
           });
}

bool verifies(config::ClientAuth client_auth) {
    switch (client_auth) {
        case config::ClientAuth::none:
        case config::ClientAuth::request:
        case config::ClientAuth::require_any:
            return false;
        case config::ClientAuth::verify_if_given:
        case config::ClientAuth::require_and_verify:
            return true;
    }
    return false;
}

// Without basic_auth_users, the CN of a client certificate the handshake verified names the user
// (gateway.md §7.1); a certificate taken unchecked names no one.
std::string certificate_user(SSL* connection, const config::HttpSettings& settings) {
    const auto& web = settings.web;
    if (!web || !web->users.empty() || !web->tls || !verifies(web->tls->client_auth)) return {};
    if (SSL_get_verify_result(connection) != X509_V_OK) return {};
    return peer_common_name(connection);
}

http::response<http::string_body> make_response(unsigned version, bool keep_alive,
                                                HttpResponse page,
                                                const config::HttpSettings& settings) {
    http::response<http::string_body> response{static_cast<http::status>(page.status), version};
    response.set(http::field::server, "ioportd/" IOPORTD_VERSION);
    response.set(http::field::content_type, page.content_type);
    // Live data: a browser or proxy must ask again, never show an old copy.
    response.set(http::field::cache_control, "no-store");
    for (const auto& [name, value] : security_headers)
        response.set(beast::string_view(name.data(), name.size()),
                     beast::string_view(value.data(), value.size()));
    if (settings.web)
        for (const auto& [name, value] : settings.web->headers)
            response.set(name, value);
    for (const auto& [name, value] : page.headers)
        response.set(name, value);
    response.keep_alive(keep_alive);
    response.body() = std::move(page.body);  // a full /api/v1/trends is over a megabyte
    response.prepare_payload();
    return response;
}

// An answer goes out as its header, written here, and its body as it is, in one Asio write per
// stream type: Beast's write operations, instantiated for each body type and stream, were two
// thirds of this file's compile time.
template <class Stream>
asio::awaitable<boost::system::error_code> send(Stream& stream,
                                                const http::response_header<>& header,
                                                std::string_view body) {
    std::ostringstream head;
    head << header;
    const auto bytes = std::move(head).str();
    const std::array buffers{asio::buffer(bytes), asio::buffer(body)};
    boost::system::error_code ec;
    co_await asio::async_write(stream, buffers, redirect_error(use_awaitable, ec));
    co_return ec;
}

}  // namespace

HttpResponse write_answer(unsigned status, std::string_view result, std::string_view error) {
    Json json;
    json.begin_object().member("result", result);
    if (!error.empty()) json.member("error", error);
    json.end_object();
    return {status, "application/json", json.take() + "\n"};
}

std::string machine_host_name() {
    std::array<char, HOST_NAME_MAX + 1> name{};
    if (::gethostname(name.data(), name.size() - 1) != 0) return {};
    return name.data();
}

Result<TlsContext> make_http_tls_context(const config::HttpSettings& settings) {
    if (!settings.web || !settings.web->tls) return TlsContext{};
    const auto& tls = *settings.web->tls;
    return make_tls_server_context({.section = "http.web_config_file tls_server_config",
                                    .certificate = tls.cert_file,
                                    .certificate_pem = tls.cert_pem,
                                    .key_pem = tls.key_pem,
                                    .client_ca_pem = tls.client_ca_pem,
                                    .client_crl_pem = {},
                                    .client_auth = tls.client_auth,
                                    .min_version = tls.min_version,
                                    .max_version = tls.max_version,
                                    .session_id_context = "ioportd-http"});
}

struct HttpServer::Connection {
    Connection(tcp::socket socket, const tcp::endpoint& from, TlsContext context)
        : address(from.address()), peer(host_port(from)), tls(std::move(context)) {
        if (tls) {
            auto& secure = stream.emplace<SecureStream>(std::move(socket), *tls);
            // OpenSSL keeps its record buffers between records (as modbus_tls.cpp says why).
            SSL_clear_mode(secure.native_handle(), SSL_MODE_RELEASE_BUFFERS);
        } else {
            stream.emplace<PlainStream>(std::move(socket));
        }
    }
    beast::tcp_stream& transport() {
        if (auto* secure = std::get_if<SecureStream>(&stream))
            return beast::get_lowest_layer(*secure);
        return std::get<PlainStream>(stream);
    }
    void close() {
        boost::system::error_code ignored;
        transport().socket().shutdown(tcp::socket::shutdown_both, ignored);
        transport().socket().close(ignored);
    }

    std::variant<std::monostate, PlainStream, SecureStream> stream;
    asio::ip::address address;
    ClientKey key{};      // its address's, as counted when it was accepted
    bool served = false;  // counted in served_: past its handshake, or plain
    std::string peer;
    TlsContext tls;                // kept while the connection lives; null for plain HTTP
    std::string certificate_user;  // certificate_user()
};

// One request and its answer.
struct HttpServer::Exchange {
    beast::flat_buffer& buffer;
    http::request_parser<http::empty_body> parser{};
    bool unread_body = false;  // the request has a body not read: the connection cannot go on
    bool head = false;
};

HttpServer::HttpServer(const asio::any_io_executor& executor, config::HttpSettings settings,
                       TlsContext tls, std::shared_ptr<Authenticator> auth, std::string host_name,
                       Log& log, HttpRefusals& refusals, HttpHandler handler)
    : executor_(executor),
      settings_(std::move(settings)),
      tls_(std::move(tls)),
      auth_(std::move(auth)),
      host_name_(std::move(host_name)),
      log_(log),
      handler_(std::move(handler)),
      accept_retry_(executor),
      refused_(refusals) {
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
    log_.info({}, "HTTP on {}://{}/ (status page, /metrics, /healthz){}", tls_ ? "https" : "http",
              host_port(local_endpoint()), auth_->required() ? ", Basic authentication" : "");
    asio::co_spawn(executor_, accept_loop(acceptor_), asio::detached);
    return {};
}

void HttpServer::stop() {
    boost::system::error_code ignored;
    if (acceptor_) acceptor_->close(ignored);
    accept_retry_.cancel();
    for (auto* connection : connections_)
        connection->close();
}

void HttpServer::apply(config::HttpSettings next, TlsContext tls) {
    const bool transport_changed = (next.web ? next.web->tls : std::nullopt) !=
                                   (settings_.web ? settings_.web->tls : std::nullopt);
    settings_ = std::move(next);
    tls_ = std::move(tls);
    set_names();
    for (auto* connection : connections_)
        if (transport_changed || !allowed(settings_.allow, connection->address))
            connection->close();
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
        const auto key = client_key(peer.address(), settings_.ipv6_prefix);
        auto& from = client(key);
        if (const auto why = refusal_of(peer, from); !why.empty()) {
            log_refusal(host_port(peer), why);
            continue;  // the socket closes as it goes out of scope
        }
        socket.set_option(tcp::no_delay(true), ec);
        auto connection = std::make_shared<Connection>(std::move(socket), peer, tls_);
        connection->key = key;
        ++from.connections;
        if (tls_) {
            ++from.handshakes;
            ++handshakes_;
        } else {
            connection->served = true;
            ++served_;
        }
        connections_.insert(connection.get());
        asio::co_spawn(executor_, serve(std::move(connection)), asio::detached);
    }
}

HttpServer::Client& HttpServer::client(const ClientKey& key) {
    // Bounded by what is open (at most max_http_connections + max_http_handshakes addresses hold
    // something) and by the addresses whose handshake tokens are still refilling.
    constexpr std::size_t max_clients = 1024;
    if (clients_.size() >= max_clients && !clients_.contains(key))
        std::erase_if(clients_, [](const auto& entry) { return entry.second.connections == 0; });
    return clients_[key];
}

std::string HttpServer::refusal_of(const tcp::endpoint& peer, Client& from) {
    if (!allowed(settings_.allow, peer.address())) {
        ++refused_.not_allowed;
        return "not in http.allow";
    }
    if (from.connections >= max_http_connections_per_address) {
        ++refused_.per_address;
        return fmt::format("{} HTTP connections open from its address",
                           max_http_connections_per_address);
    }
    if (!tls_) {
        if (served_ < max_http_connections) return {};
        ++refused_.too_many;
        return fmt::format("{} HTTP connections open", max_http_connections);
    }
    const auto now = std::chrono::steady_clock::now();
    const std::chrono::duration<double> since = now - from.refilled;
    from.tokens =
        std::min(http_handshake_burst, from.tokens + since.count() * http_handshakes_per_second);
    from.refilled = now;
    std::string why;
    if (handshakes_ >= max_http_handshakes)
        why = fmt::format("{} TLS handshakes under way", max_http_handshakes);
    else if (from.handshakes >= max_http_handshakes_per_address)
        why = fmt::format("{} TLS handshakes under way from its address",
                          max_http_handshakes_per_address);
    else if (from.tokens < 1)
        why = fmt::format("more than {} TLS handshakes a second from its address",
                          http_handshakes_per_second);
    if (why.empty()) {
        from.tokens -= 1;
        return {};
    }
    ++refused_.too_many_handshakes;
    return why;
}

void HttpServer::closed(Connection& c) {
    const auto from = clients_.find(c.key);
    if (from != clients_.end()) --from->second.connections;
    if (c.served) --served_;
    connections_.erase(&c);
}

asio::awaitable<void> HttpServer::serve(std::shared_ptr<Connection> c) {
    const auto self = shared_from_this();
    if (auto* secure = std::get_if<SecureStream>(&c->stream)) {
        boost::system::error_code ec;
        c->transport().expires_after(http_request_timeout);
        co_await secure->async_handshake(asio::ssl::stream_base::server,
                                         redirect_error(use_awaitable, ec));
        --handshakes_;
        if (const auto from = clients_.find(c->key); from != clients_.end())
            --from->second.handshakes;
        if (ec) {
            ++refused_.tls_handshake;
            log_refusal(c->peer, fmt::format("TLS handshake failed: {}",
                                             handshake_failure(ec, secure->native_handle())));
        } else if (served_ >= max_http_connections) {
            ++refused_.too_many;
            log_refusal(c->peer, fmt::format("{} HTTP connections open", max_http_connections));
        } else {
            c->served = true;
            ++served_;
            c->certificate_user = certificate_user(secure->native_handle(), settings_);
            co_await exchange(*c, *secure);
        }
    } else {
        co_await exchange(*c, std::get<PlainStream>(c->stream));
    }
    c->close();
    closed(*c);
}

template <class Stream>
asio::awaitable<void> HttpServer::exchange(Connection& c, Stream& stream) {
    beast::flat_buffer buffer(http_header_limit);
    bool first = true;
    for (;;) {
        boost::system::error_code ec;
        // A kept-alive connection may wait idle for its next request; a new one must send its
        // first request at once, whole, within the request timeout.
        if (!first && buffer.size() == 0) {
            c.transport().expires_after(http_idle_timeout);
            const auto n = co_await stream.async_read_some(buffer.prepare(http_header_limit),
                                                           redirect_error(use_awaitable, ec));
            if (ec) break;
            buffer.commit(n);
        }
        first = false;
        c.transport().expires_after(http_request_timeout);
        Exchange x{buffer};
        x.parser.header_limit(http_header_limit);
        co_await http::async_read_header(stream, buffer, x.parser,
                                         redirect_error(use_awaitable, ec));
        if (ec == http::error::end_of_stream || ec == beast::error::timeout ||
            ec == asio::error::operation_aborted || ec == asio::error::connection_reset ||
            ec == asio::ssl::error::stream_truncated)
            break;
        HttpResponse page;
        unsigned version = 11;
        bool keep_alive = false;
        if (ec) {
            page = text(ec == http::error::header_limit ? 431u : 400u,
                        fmt::format("bad request: {}", ec.message()));
        } else {
            version = x.parser.get().version();
            keep_alive = x.parser.get().keep_alive();
            // Headers only, whatever the answer (a refusal too): a body after them would be read
            // as the next answer on a kept-alive connection.
            x.head = x.parser.get().method() == http::verb::head;
            x.unread_body = !x.parser.is_done();
            page = co_await answer(c, stream, x);
        }
        auto response =
            make_response(version, keep_alive && !x.unread_body, std::move(page), settings_);
        c.transport().expires_after(http_request_timeout);
        ec = co_await send(stream, response, x.head ? std::string_view{} : response.body());
        if (ec || !response.keep_alive()) break;
    }
}

template <class Stream>
asio::awaitable<HttpResponse> HttpServer::answer(Connection& c, Stream& stream, Exchange& x) {
    const auto& request = x.parser.get();
    const Request line{view(request.method_string()),
                       view(request.target()),
                       request.version(),
                       request.count(http::field::host),
                       view(request[http::field::host]),
                       settings_.web.has_value()};
    if (auto refusal = host_refusal(line, names_)) {
        if (refusal->status == 421)
            log_refusal(c.peer, fmt::format("Host {} is not this server's name (421): if it is, "
                                            "add it to http.server_names",
                                            printable(line.host)));
        co_return text(refusal->status, refusal->message);
    }
    const auto routed = route(line.method, line.target, line.writes);
    const bool write = routed && routed->page == Page::write;
    Caller caller{.user = c.certificate_user, .operator_ = false, .address = c.address};
    if (auth_->required())
        if (auto refused =
                co_await authenticate(c, view(request[http::field::authorization]), write, caller))
            co_return *std::move(refused);
    caller.operator_ =
        !caller.user.empty() &&
        std::ranges::find(settings_.operators, caller.user) != settings_.operators.end();
    if (!routed) {
        HttpResponse refused = text(routed.error().status, routed.error().message);
        if (routed.error().status == 405)
            refused.headers.emplace_back("Allow", routed.error().allow);
        co_return refused;
    }
    HttpCall call{*routed, std::move(caller), {}};
    if (write) co_return co_await read_write(c, stream, x, call);
    // A page's request with a body (a form's POST is refused above for its method).
    if (x.unread_body) co_return text(413, "this page takes no request body");
    co_return co_await handler_(std::move(call));
}

asio::awaitable<std::optional<HttpResponse>> HttpServer::authenticate(
    Connection& c, std::string_view authorization, bool write, Caller& caller) {
    // Made apart from the co_await, as in Authenticator::check: no temporary in its expression.
    auto check = auth_->check(c.address, std::string(authorization));
    const auto outcome = co_await std::move(check);
    switch (outcome.verdict) {
        case AuthVerdict::authenticated:
            caller.user = outcome.user;
            co_return std::nullopt;
        case AuthVerdict::missing:
        case AuthVerdict::refused: {
            auto refused = refusal(write, 401, "unauthorized",
                                   "this server needs a user and password (Basic)");
            refused.headers.emplace_back("WWW-Authenticate",
                                         "Basic realm=\"ioportd\", charset=\"UTF-8\"");
            co_return refused;
        }
        case AuthVerdict::limited: {
            const auto wait = std::chrono::ceil<std::chrono::seconds>(outcome.retry_at -
                                                                      Authenticator::Clock::now());
            auto refused = refusal(write, 429, "limited",
                                   "too many password checks from this address (five a minute, "
                                   "one at a time): try again later");
            refused.headers.emplace_back(
                "Retry-After", std::to_string(std::max(wait, std::chrono::seconds{1}).count()));
            co_return refused;
        }
        case AuthVerdict::busy: {
            auto refused = refusal(write, 503, "busy",
                                   "too many addresses are signing in at once: try again in a "
                                   "second");
            refused.headers.emplace_back("Retry-After", "1");
            co_return refused;
        }
    }
    co_return text(500, "unknown verdict");
}

template <class Stream>
asio::awaitable<HttpResponse> HttpServer::read_write(Connection& c, Stream& stream, Exchange& x,
                                                     HttpCall& call) {
    const auto& request = x.parser.get();
    if (!call.caller.operator_)
        co_return write_answer(
            403, "forbidden",
            call.caller.user.empty()
                ? "writes are for the users in http.operators: sign in as one"
                : fmt::format("user '{}' is not one of http.operators", call.caller.user));
    // A page of another origin can send a form (text/plain, no preflight) but not JSON without
    // the browser asking this server first, which it refuses (405 to OPTIONS).
    if (!json_content(view(request[http::field::content_type])))
        co_return write_answer(415, "unsupported_media_type",
                               "a write's body is JSON: Content-Type: application/json");
    if (!same_origin(view(request[http::field::origin]), c.tls != nullptr,
                     view(request[http::field::host])))
        co_return write_answer(403, "forbidden",
                               fmt::format("a page of another origin ({}) may not write",
                                           printable(view(request[http::field::origin]), 80)));
    if (const auto length = x.parser.content_length(); length && *length > max_write_body)
        co_return write_answer(413, "too_large",
                               fmt::format("a write's body is at most {} bytes", max_write_body));
    boost::system::error_code ec;
    if (beast::iequals(request[http::field::expect], "100-continue")) {
        http::response_header<> go_on;
        go_on.result(http::status::continue_);
        go_on.version(request.version());
        if (const auto failed = co_await send(stream, go_on, {}))
            co_return write_answer(400, "bad_request", failed.message());
    }
    http::request_parser<http::string_body> body{std::move(x.parser)};
    body.body_limit(max_write_body);
    co_await http::async_read(stream, x.buffer, body, redirect_error(use_awaitable, ec));
    if (ec == http::error::body_limit)
        co_return write_answer(413, "too_large",
                               fmt::format("a write's body is at most {} bytes", max_write_body));
    if (ec) co_return write_answer(400, "bad_request", fmt::format("the body: {}", ec.message()));
    x.unread_body = false;
    call.body = std::move(body.get().body());
    co_return co_await handler_(std::move(call));
}

}  // namespace ioport::daemon
