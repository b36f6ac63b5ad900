#include "daemon/http/http_output.hpp"

namespace ioport::daemon {

HttpOutput::HttpOutput(const asio::any_io_executor& executor, Log& log, std::string host_name,
                       std::function<GatewayView()> view)
    : executor_(executor), log_(log), host_name_(std::move(host_name)), view_(std::move(view)) {}

std::shared_ptr<HttpServer> HttpOutput::make(const config::HttpSettings& settings) {
    return std::make_shared<HttpServer>(
        executor_, settings, host_name_, log_,
        [this](const Route& route) { return render_page(view_(), route); });
}

Result<> HttpOutput::start(const config::GatewayConfig& config, const Links& /*links*/) {
    settings_ = config.http;
    if (!settings_) return {};
    server_ = make(*settings_);
    return server_->start();
}

// A new address is bound now, so that a reload fails, changing nothing, when it cannot be.
Result<> HttpOutput::prepare(const config::GatewayConfig& next) {
    abandon();
    if (!next.http) return {};
    if (server_ && server_->settings().listen_host == next.http->listen_host &&
        server_->settings().listen_port == next.http->listen_port)
        return {};
    auto server = make(*next.http);
    if (auto started = server->start(); !started) {
        server->stop();
        return started;
    }
    next_ = std::move(server);
    return {};
}

void HttpOutput::abandon() {
    if (next_) next_->stop();
    next_.reset();
}

bool HttpOutput::apply(const config::GatewayConfig& next, const Links& /*links*/) {
    const bool changed = next.http != settings_;
    settings_ = next.http;
    if (!next.http || next_) {
        if (server_) {
            server_->stop();
            if (!next.http) log_.info({}, "HTTP server stopped: no http section any more");
        }
        server_ = std::exchange(next_, nullptr);
    } else {
        server_->apply(*next.http);
    }
    return changed;
}

void HttpOutput::stop(std::chrono::milliseconds /*deadline*/, std::function<void()> done) {
    if (server_) server_->stop();
    done();
}

}  // namespace ioport::daemon
