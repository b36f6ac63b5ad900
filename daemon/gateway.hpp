// The running gateway: one LinkScheduler per configured link, the Modbus server in front of them,
// the read-only HTTP side, the Sparkplug edge node and the plain MQTT (JSON) output, on one
// io_context. Started and stopped in a fixed order: links first (so the first clients find ports
// already being opened), then the Modbus server, HTTP, Sparkplug, MQTT JSON; stopped the other
// way round.
// A reload swaps in a new configuration while running, touching only what it changes.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/core/events.hpp"
#include "daemon/core/link_scheduler.hpp"
#include "daemon/disk_thread.hpp"
#include "daemon/http/http_server.hpp"
#include "daemon/http/render.hpp"
#include "daemon/modbus/modbus_server.hpp"
#include "daemon/mqtt_json/mqtt_json_output.hpp"
#include "daemon/sparkplug/sparkplug_node.hpp"

namespace ioport::daemon {

class Gateway {
  public:
    // `disk`: the daemon's disk thread (the Sparkplug store's), which outlives the gateway.
    Gateway(const asio::any_io_executor& executor, config::GatewayConfig config, Log& log,
            DiskThread& disk);

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

    // What the HTTP side shows.
    GatewayView view() const;
    // Where the gateway's parts tell what happened; main tells a refused reload there.
    EventBus& bus() { return bus_; }
    // The HTTP server's address; nullopt when it is off.
    std::optional<asio::ip::tcp::endpoint> http_endpoint() const;

  private:
    // A new link, telling the bus.
    std::shared_ptr<LinkScheduler> make_link(const config::LinkConfig& link);
    std::shared_ptr<HttpServer> make_http(const config::HttpSettings& settings);
    // A reload's first HTTP step: binds the new address, if it moved (into next_http_).
    Result<> prepare_http(const std::optional<config::HttpSettings>& next);
    void apply_http(const std::optional<config::HttpSettings>& next);
    Result<> start_sparkplug(std::uint64_t next_bdseq = 0);
    Result<> start_mqtt_json();
    // What the configuration weakens (config::warnings), at start-up and after each reload.
    void log_warnings();

    asio::any_io_executor executor_;
    config::GatewayConfig config_;
    Log& log_;
    DiskThread& disk_;
    const std::string host_name_ = machine_host_name();  // read once: HTTP's Host check
    // Before everything that tells it something, so that it outlives them.
    EventBus bus_;
    EventLog events_;                  // for the status page
    EventBus::Subscription recorded_;  // of events_, a subscriber like any other
    std::chrono::system_clock::time_point started_ = std::chrono::system_clock::now();
    Links links_;
    std::shared_ptr<ModbusServer> server_;
    std::shared_ptr<HttpServer> http_;
    std::shared_ptr<HttpServer> next_http_;  // bound by prepare_http(), taken by apply_http()
    std::shared_ptr<SparkplugNode> sparkplug_;
    std::shared_ptr<MqttJsonOutput> mqtt_json_;
};

// The lines printed by --check-config: the links, their modules and the Modbus front.
std::string check_config_text(const config::GatewayConfig& config);

}  // namespace ioport::daemon
