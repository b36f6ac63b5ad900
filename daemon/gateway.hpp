// The running gateway: one LinkScheduler per configured link, and the outputs in front of them
// (core/output.hpp) in one list: the Modbus server, the HTTP side, the Sparkplug node and the
// plain MQTT (JSON) output, on one io_context. Started in a fixed order: links first (so the
// first clients find ports already being opened), then the outputs in the list's order; stopped
// the other way round. A reload swaps in a new configuration while running, touching only what
// it changes. The gateway's own policy lives here too: what a communication loss does.
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/base/worker_thread.hpp"
#include "daemon/core/bus.hpp"
#include "daemon/core/comm_loss.hpp"
#include "daemon/core/events.hpp"
#include "daemon/core/link_scheduler.hpp"
#include "daemon/core/output.hpp"
#include "daemon/http/http_output.hpp"
#include "daemon/modbus/modbus_output.hpp"

namespace ioport::daemon {

class Gateway {
  public:
    // `disk`, `hashing`: the daemon's threads for the Sparkplug store's files and the HTTP side's
    // passwords (worker_thread.hpp), which outlive the gateway.
    Gateway(const asio::any_io_executor& executor, config::GatewayConfig config, Log& log,
            WorkerThread& disk, WorkerThread& hashing);

    Result<> start();
    // The orderly end: no new requests; writes in flight finish; the outputs are set as
    // on_shutdown says; `done` is called when every link has closed its port and every output
    // has finished.
    void shut_down(std::function<void()> done);
    // The abrupt end, for when shut_down() takes too long: everything is cancelled now.
    void stop();

    // Applies a new configuration. Links whose settings are unchanged keep running (port, image,
    // queued writes); changed ones are restarted, removed ones stopped, new ones started. Client
    // connections stay unless the new allow list refuses them. Fails, changing nothing, when an
    // output cannot take it (a listen address that cannot be bound, a store directory refused).
    // On success, what changed, in one line.
    Result<std::string> reload(config::GatewayConfig next);

    const config::GatewayConfig& config() const { return config_; }
    // "2 of 2 links up, 9 of 9 modules online, 3 clients"
    std::string summary() const;
    // Every link's loop is making progress (see LinkScheduler::progressing).
    bool healthy() const;
    // Where the gateway's parts tell what happened; main tells a refused reload there.
    EventBus& bus() { return bus_; }

  private:
    std::shared_ptr<LinkScheduler> make_link(const config::LinkConfig& link);
    GatewayView view() const;
    // A communication loss (gateway.md §5.3): every link to its safe state.
    void comm_lost();
    // What the configuration weakens (config::warnings), at start-up and after each reload.
    void log_warnings();

    asio::any_io_executor executor_;
    config::GatewayConfig config_;
    Log& log_;
    WorkerThread& disk_;
    // Before everything that tells it something, so that it outlives them.
    EventBus bus_;
    EventLog events_;                  // for the status page
    EventBus::Subscription recorded_;  // of events_, a subscriber like any other
    std::chrono::system_clock::time_point started_ = std::chrono::system_clock::now();
    Links links_;
    std::shared_ptr<CommLossWatch> comm_loss_;
    std::shared_ptr<ModbusOutput> modbus_;  // the first output: its clients are the summary's
    Outputs outputs_;  // Modbus, HTTP, Sparkplug, plain MQTT: started in this order
};

}  // namespace ioport::daemon
