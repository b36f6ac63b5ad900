// Sparkplug B (gateway.md §5.5, §6.2) as one of the gateway's outputs (core/output.hpp): the
// edge node of the mqtt section, made anew when a reload changes the section (bdSeq going on from
// the last), and what it shows on /metrics and in the state API. Nothing when the section is
// absent.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>

#include "daemon/base/worker_thread.hpp"
#include "daemon/core/output.hpp"
#include "daemon/sparkplug/sparkplug_node.hpp"

namespace ioport::daemon {

class SparkplugOutput final : public Output {
  public:
    SparkplugOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus,
                    WorkerThread& disk);

    std::string_view name() const override { return "MQTT"; }
    Result<> start(const config::GatewayConfig& config, const Links& links) override;
    // A new store directory is refused before anything changes (gateway.md §6.2).
    Result<> prepare(const config::GatewayConfig& next) override;
    bool apply(const config::GatewayConfig& next, const Links& links) override;
    void stop(std::chrono::milliseconds deadline, std::function<void()> done) override;
    void metrics(Exposition& out) const override;
    void state(Json& out) const override;

  private:
    Result<> start_node(const config::GatewayConfig& config, const Links& links);

    asio::any_io_executor executor_;
    Log& log_;
    EventBus& bus_;
    WorkerThread& disk_;
    std::optional<config::MqttSettings> settings_;
    std::shared_ptr<SparkplugNode> node_;  // null when the section is absent
    std::optional<std::uint64_t>
        next_bdseq_;  // of the next node's first CONNECT; none: the store's
};

}  // namespace ioport::daemon
