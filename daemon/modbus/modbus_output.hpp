// The Modbus TCP front (gateway.md §3–§5.6) as one of the gateway's outputs (core/output.hpp):
// its server, started, reloaded and stopped through the seam, and what it shows on /metrics and
// in the state API.
#pragma once

#include <memory>

#include "daemon/core/comm_loss.hpp"
#include "daemon/core/output.hpp"
#include "daemon/modbus/modbus_server.hpp"

namespace ioport::daemon {

class ModbusOutput final : public Output {
  public:
    // `comm_loss`: the gateway's watch, which every request that shows a SCADA is there tells.
    ModbusOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus,
                 std::shared_ptr<CommLossWatch> comm_loss);

    std::string_view name() const override { return "Modbus settings"; }
    Result<> start(const config::GatewayConfig& config, const Links& links) override;
    // Binds the new listen addresses, if they moved, and reads the TLS files anew.
    Result<> prepare(const config::GatewayConfig& next) override;
    void abandon() override;
    bool apply(const config::GatewayConfig& next, const Links& links) override;
    // With a deadline: no new requests, and a connection waiting for a write's outcome closes
    // once its response is sent (the links finish the writes); without, every connection now.
    void stop(std::chrono::milliseconds deadline, std::function<void()> done) override;
    void metrics(Exposition& out) const override;
    void state(Json& out) const override;

    // Clients connected now (the gateway's summary).
    std::size_t connections() const { return server_ ? server_->connections() : 0; }

  private:
    asio::any_io_executor executor_;
    Log& log_;
    EventBus& bus_;
    std::shared_ptr<CommLossWatch> comm_loss_;
    std::shared_ptr<ModbusServer> server_;
};

}  // namespace ioport::daemon
