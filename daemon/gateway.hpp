// The running gateway: one LinkScheduler per configured link and the Modbus server in front of
// them, on one io_context. Started and stopped in a fixed order: links first (so the first
// clients find ports already being opened), server last; stopped the other way round.
// A reload swaps in a new configuration while running, touching only what it changes.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/link_scheduler.hpp"
#include "daemon/modbus_server.hpp"

namespace ioport::daemon {

class Gateway {
  public:
    Gateway(const asio::any_io_executor& executor, config::GatewayConfig config, Log& log);

    Result<> start();
    // The orderly end: no new requests; writes in flight finish; the outputs are set as
    // on_shutdown says; `done` is called when every link has closed its port.
    void shut_down(std::function<void()> done);
    // The abrupt end, for when shut_down() takes too long: everything is cancelled now.
    void stop();

    // Applies a new configuration. Links whose settings are unchanged keep running (port, image,
    // queued writes); changed ones are restarted, removed ones stopped, new ones started. Client
    // connections stay unless the new allow list refuses them. Fails, changing nothing, when the
    // new listen address cannot be bound. On success, what changed, in one line.
    Result<std::string> reload(config::GatewayConfig next);

    const config::GatewayConfig& config() const { return config_; }
    // "2 of 2 links up, 9 of 9 modules online, 3 clients"
    std::string summary() const;
    // Every link's loop is making progress (see LinkScheduler::progressing).
    bool healthy() const;

  private:
    std::shared_ptr<LinkScheduler> make_link(const config::LinkConfig& link) const;

    asio::any_io_executor executor_;
    config::GatewayConfig config_;
    Log& log_;
    ModbusServer::Units links_;
    std::unique_ptr<ModbusServer> server_;
};

// The lines printed by --check-config: the links, their modules and the Modbus front.
std::string describe(const config::GatewayConfig& config);

}  // namespace ioport::daemon
