// Plain MQTT (gateway.md §6.3) as one of the gateway's outputs (core/output.hpp): the session of
// the mqtt_json section, made anew when a reload changes the section, and what it shows on
// /metrics and in the state API. Nothing when the section is absent.
#pragma once

#include <memory>
#include <optional>

#include "daemon/core/output.hpp"
#include "daemon/mqtt_json/mqtt_json_session.hpp"

namespace ioport::daemon {

class MqttJsonOutput final : public Output {
  public:
    MqttJsonOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus);

    std::string_view name() const override { return "MQTT JSON"; }
    Result<> start(const config::GatewayConfig& config, const Links& links) override;
    Result<> prepare(const config::GatewayConfig& next) override;
    bool apply(const config::GatewayConfig& next, const Links& links) override;
    void stop(std::chrono::milliseconds deadline, std::function<void()> done) override;
    void metrics(Exposition& out) const override;
    void state(Json& out) const override;

  private:
    Result<> start_session(const config::GatewayConfig& config, const Links& links);

    asio::any_io_executor executor_;
    Log& log_;
    EventBus& bus_;
    std::optional<config::MqttJsonSettings> settings_;
    std::shared_ptr<MqttJsonSession> session_;  // null when the section is absent
};

}  // namespace ioport::daemon
