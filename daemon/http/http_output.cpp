#include "daemon/http/http_output.hpp"

#include <algorithm>

#include "protocol/points.hpp"

namespace ioport::daemon {
namespace {

std::map<std::string, std::string> users_of(const std::optional<config::HttpSettings>& settings) {
    if (!settings || !settings->web) return {};
    return settings->web->users;
}

// A write the link finished, answered as gateway.md §7.1 says.
HttpResponse write_outcome(WriteResult result, const config::LinkConfig& link) {
    switch (result) {
        case WriteResult::confirmed:
            return write_answer(200, "confirmed");
        case WriteResult::busy: {
            auto answer = write_answer(
                503, "busy",
                fmt::format("{} writes are waiting for link {} (max_pending_writes): try again in "
                            "a second",
                            link.max_pending_writes, link.name));
            answer.headers.emplace_back("Retry-After", "1");
            return answer;
        }
        case WriteResult::error_ack:
            return write_answer(504, "error_ack", "the module refused the command (error ack)");
        case WriteResult::no_answer:
            return write_answer(504, "no_answer", "the module did not answer");
        case WriteResult::link_down:
            return write_answer(504, "link_down",
                                fmt::format("link {}'s serial port is not open", link.name));
        case WriteResult::dropped:
            return write_answer(504, "dropped",
                                "a communication loss dropped the write before it was sent");
    }
    return write_answer(504, "no_answer", "unknown outcome");
}

}  // namespace

HttpOutput::HttpOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus,
                       WorkerThread& hashing, std::string host_name,
                       std::function<GatewayView()> view)
    : executor_(executor),
      log_(log),
      bus_(bus),
      host_name_(std::move(host_name)),
      view_(std::move(view)),
      auth_(std::make_shared<Authenticator>(executor, hashing, log)) {}

std::shared_ptr<HttpServer> HttpOutput::make(const config::HttpSettings& settings, TlsContext tls) {
    // The output outlives its servers' requests: the gateway stops them before it goes.
    return std::make_shared<HttpServer>(executor_, settings, std::move(tls), auth_, host_name_,
                                        log_, connections_refused_,
                                        [this](HttpCall call) { return answer(std::move(call)); });
}

void HttpOutput::set_users() {
    auth_->set_users(users_of(settings_));
    auth_->set_ipv6_prefix(settings_ ? settings_->ipv6_prefix : config::default_ipv6_prefix);
}

Result<> HttpOutput::start(const config::GatewayConfig& config, const Links& /*links*/) {
    settings_ = config.http;
    set_users();
    if (!settings_) return {};
    auto tls = make_http_tls_context(*settings_);
    if (!tls) return Unexpected(tls.error());
    server_ = make(*settings_, *std::move(tls));
    return server_->start();
}

// A new address is bound now, and a new TLS context made, so that a reload fails, changing
// nothing, when either cannot be.
Result<> HttpOutput::prepare(const config::GatewayConfig& next) {
    abandon();
    if (!next.http) return {};
    auto tls = make_http_tls_context(*next.http);
    if (!tls) return Unexpected(tls.error());
    next_tls_ = *std::move(tls);
    if (server_ && server_->settings().listen_host == next.http->listen_host &&
        server_->settings().listen_port == next.http->listen_port)
        return {};
    auto server = make(*next.http, next_tls_);
    if (auto started = server->start(); !started) {
        server->stop();
        next_tls_.reset();
        return started;
    }
    next_ = std::move(server);
    return {};
}

void HttpOutput::abandon() {
    if (next_) next_->stop();
    next_.reset();
    next_tls_.reset();
}

bool HttpOutput::apply(const config::GatewayConfig& next, const Links& /*links*/) {
    const bool changed = next.http != settings_;
    settings_ = next.http;
    set_users();
    if (!next.http || next_) {
        if (server_) {
            server_->stop();
            if (!next.http) log_.info({}, "HTTP server stopped: no http section any more");
        }
        server_ = std::exchange(next_, nullptr);
    } else if (changed) {
        server_->apply(*next.http, next_tls_);
    }
    next_tls_.reset();
    return changed;
}

void HttpOutput::stop(std::chrono::milliseconds /*deadline*/, std::function<void()> done) {
    if (server_) server_->stop();
    done();
}

void HttpOutput::metrics(Exposition& out) const {
    if (!settings_) return;
    const auto& refused = connections_refused_;
    out.family("ioportd_http_connections_refused_total", "counter",
               "HTTP connections closed unserved, by reason");
    for (const auto& [reason, count] :
         {std::pair{"not_allowed", refused.not_allowed}, std::pair{"too_many", refused.too_many},
          std::pair{"per_address", refused.per_address},
          std::pair{"too_many_handshakes", refused.too_many_handshakes},
          std::pair{"tls_handshake", refused.tls_handshake}})
        out.sample("ioportd_http_connections_refused_total", {{"reason", reason}}, count);
    if (!settings_->web) return;
    out.family("ioportd_http_auth_failures_total", "counter",
               "HTTP requests refused for wrong or malformed credentials");
    out.sample("ioportd_http_auth_failures_total", {}, auth_->failures());
    out.family("ioportd_http_auth_refused_total", "counter",
               "HTTP requests refused without a password check, by reason");
    out.sample("ioportd_http_auth_refused_total", {{"reason", "limited"}}, auth_->limited());
    out.sample("ioportd_http_auth_refused_total", {{"reason", "busy"}}, auth_->busy());
}

asio::awaitable<HttpResponse> HttpOutput::answer(HttpCall call) {
    if (call.route.page == Page::write) co_return co_await write(std::move(call));
    co_return render_page(view_(), call.route, call.caller, metrics_bytes_);
}

HttpResponse HttpOutput::refuse(const HttpCall& call, unsigned status, std::string_view result,
                                std::string_view link, std::string error) {
    const auto client =
        fmt::format("http {}@{}", call.caller.user, call.caller.address.to_string());
    const auto held = refusals_.admit(fmt::format("{} {}", call.caller.user, result),
                                      std::chrono::steady_clock::now());
    if (held) {
        const auto text = fmt::format("HTTP write by {} refused ({}): {}{}", client, result, error,
                                      held_back(*held));
        log_.warn({.link = std::string(link), .client = client},
                  "{} (logged once a minute per user and reason)", text);
        bus_.publish(Note{.kind = EventKind::write, .link = link, .client = client, .text = text});
    }
    return write_answer(status, result, error);
}

// POST /api/v1/write (gateway.md §7.1): planned as every output plans a write, then the link's.
asio::awaitable<HttpResponse> HttpOutput::write(HttpCall call) {
    auto body = parse_write_body(call.body);
    if (!body) co_return refuse(call, 400, "bad_request", {}, std::move(body).error());
    const auto view = view_();
    const auto link = std::ranges::find_if(
        view.links, [&](const auto& l) { return l->config().name == body->link; });
    if (link == view.links.end())
        co_return refuse(call, 404, "not_found", {},
                         fmt::format("no link named '{}'", printable(body->link, 40)));
    const auto& name = (*link)->config().name;
    const auto& modules = (*link)->modules();
    const auto module = std::ranges::find_if(modules, [&](const ModuleState& m) {
        return gateway::module_id(m.address) == body->module;
    });
    if (module == modules.end())
        co_return refuse(
            call, 404, "not_found", name,
            fmt::format("link {} has no module '{}'", name, printable(body->module, 40)));
    const auto type = module->address ? std::optional(module->address->type) : std::nullopt;
    if (!gateway::find_point(type, body->point))
        co_return refuse(
            call, 404, "not_found", name,
            fmt::format("{} has no point '{}'", body->module, printable(body->point, 40)));
    if (view.config.modbus.read_only)
        co_return refuse(call, 403, "forbidden", name,
                         "modbus.read_only is set: nothing is written on a client's behalf");
    auto plan = gateway::plan_text_write(module->address, body->point, body->value);
    if (!plan) co_return refuse(call, 400, "invalid_value", name, plan.error().message);
    const auto address = fmt::format("{}/{}/{}", name, body->module, body->point);
    const auto value = printable(body->value, 40);
    WriteOrigin origin{
        .client = fmt::format("http {}@{}", call.caller.user, call.caller.address.to_string()),
        .function = "POST",
        .address = address,
        .value = value,
        .request = fmt::format("write {} = {}", address, value)};
    // The link, not the view: a reload may replace the gateway's list while this waits, and the
    // copy of the pointer keeps the link alive until the write's outcome is known.
    const auto target = *link;  // NOLINT(performance-unnecessary-copy-initialization)
    const auto result = co_await target->write(*std::move(plan), std::move(origin));
    co_return write_outcome(result, target->config());
}

}  // namespace ioport::daemon
