// The running gateway: one LinkScheduler per configured link and the Modbus server in front of
// them, on one io_context. Started and stopped in a fixed order: links first (so the first
// clients find ports already being opened), server last; stopped the other way round.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/link_scheduler.hpp"
#include "daemon/modbus_server.hpp"

namespace ioport::daemon {

class Gateway {
  public:
    Gateway(const asio::any_io_executor& executor, config::GatewayConfig config);

    Result<> start();
    void stop();

    // "2 of 2 links up, 9 of 9 modules online, 3 clients"
    std::string summary() const;
    // Every link's loop is making progress (see LinkScheduler::progressing).
    bool healthy() const;

  private:
    config::GatewayConfig config_;
    std::vector<std::unique_ptr<LinkScheduler>> links_;
    std::unique_ptr<ModbusServer> server_;
};

// The lines printed by --check-config: the links, their modules and the Modbus front.
std::string describe(const config::GatewayConfig& config);

}  // namespace ioport::daemon
