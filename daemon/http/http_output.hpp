// The HTTP side (gateway.md §5.4) as one of the gateway's outputs (core/output.hpp): its server,
// bound anew when a reload moves its address (before anything changes) and otherwise kept, and
// the pages it renders of the running gateway, every output through the seam.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "daemon/core/output.hpp"
#include "daemon/http/http_server.hpp"
#include "daemon/http/render.hpp"

namespace ioport::daemon {

class HttpOutput final : public Output {
  public:
    // `view`: what the pages render, taken for each request (a reload may change it between
    // two). `host_name`: the machine's (HttpServer).
    HttpOutput(const asio::any_io_executor& executor, Log& log, std::string host_name,
               std::function<GatewayView()> view);

    std::string_view name() const override { return "HTTP"; }
    Result<> start(const config::GatewayConfig& config, const Links& links) override;
    Result<> prepare(const config::GatewayConfig& next) override;
    void abandon() override;
    bool apply(const config::GatewayConfig& next, const Links& links) override;
    void stop(std::chrono::milliseconds deadline, std::function<void()> done) override;
    // The HTTP side has no families or members of its own.
    void metrics(Exposition& /*out*/) const override {}
    void state(Json& /*out*/) const override {}

  private:
    std::shared_ptr<HttpServer> make(const config::HttpSettings& settings);

    asio::any_io_executor executor_;
    Log& log_;
    std::string host_name_;
    std::function<GatewayView()> view_;
    std::optional<config::HttpSettings> settings_;
    std::shared_ptr<HttpServer> server_;  // null when the section is absent
    std::shared_ptr<HttpServer> next_;    // bound by prepare(), taken by apply()
};

}  // namespace ioport::daemon
