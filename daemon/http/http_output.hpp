// The HTTP side (gateway.md §5.4, §7.1) as one of the gateway's outputs (core/output.hpp): its
// server, bound anew when a reload moves its address (before anything changes) and otherwise
// kept; the pages it renders of the running gateway, every output through the seam; and the
// operators' writes (POST /api/v1/write), through the one write path.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "daemon/base/worker_thread.hpp"
#include "daemon/core/bus.hpp"
#include "daemon/core/output.hpp"
#include "daemon/http/http_auth.hpp"
#include "daemon/http/http_server.hpp"
#include "daemon/http/render.hpp"

namespace ioport::daemon {

class HttpOutput final : public Output, public std::enable_shared_from_this<HttpOutput> {
  public:
    // `view`: what the pages render, taken for each request (a reload may change it between
    // two). `host_name`: the machine's (HttpServer). `hashing`: where passwords are checked.
    HttpOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus,
               WorkerThread& hashing, std::string host_name, std::function<GatewayView()> view);

    std::string_view name() const override { return "HTTP"; }
    Result<> start(const config::GatewayConfig& config, const Links& links) override;
    Result<> prepare(const config::GatewayConfig& next) override;
    void abandon() override;
    bool apply(const config::GatewayConfig& next, const Links& links) override;
    void stop(std::chrono::milliseconds deadline, std::function<void()> done) override;
    // ioportd_http_connections_refused_total; with a web configuration
    // ioportd_http_auth_failures_total and ioportd_http_auth_refused_total. The HTTP side has no
    // state members of its own.
    void metrics(Exposition& out) const override;
    void state(Json& /*out*/) const override {}

  private:
    // The web configuration's users and http.ipv6_prefix, to the authenticator.
    void set_users();
    std::shared_ptr<HttpServer> make(const config::HttpSettings& settings, TlsContext tls);
    asio::awaitable<HttpResponse> answer(HttpCall call);
    asio::awaitable<HttpResponse> write(HttpCall call);
    HttpResponse refuse(const HttpCall& call, unsigned status, std::string_view result,
                        std::string_view link, std::string error);

    asio::any_io_executor executor_;
    Log& log_;
    EventBus& bus_;
    std::string host_name_;
    std::function<GatewayView()> view_;
    std::shared_ptr<Authenticator> auth_;
    std::optional<config::HttpSettings> settings_;
    std::shared_ptr<HttpServer> server_;  // null when the section is absent
    std::shared_ptr<HttpServer> next_;    // bound by prepare(), taken by apply()
    TlsContext next_tls_;                 // made by prepare(), taken by apply()
    LogLimiter refusals_;
    HttpRefusals connections_refused_;
    std::size_t metrics_bytes_ = 0;  // the last /metrics, reserved for the next (render_page)
};

}  // namespace ioport::daemon
