// The seam every northbound output implements: a room that renders the read model for the
// clients outside (Modbus TCP, HTTP, Sparkplug B, plain MQTT). The gateway keeps them in one list
// and starts, reloads and stops each the same way, in the list's order (stopped the other way
// round); the HTTP side shows each through metrics() and state() without knowing its type.
// Adding an output is its room and one line where the gateway makes the list (docs/design.md).
//
// An output takes the module changes it publishes from the bus (core/bus.hpp) and writes through
// LinkScheduler::write(), the one write path; it tells the bus what it refuses. An output whose
// section is absent is there all the same, doing nothing and showing what the section's absence
// shows (a null member, no families), so that a reload may add or remove the section.
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <string_view>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/core/link_scheduler.hpp"
#include "protocol/error.hpp"
#include "protocol/exposition.hpp"
#include "protocol/json.hpp"

namespace ioport::daemon {

// An orderly stop gets this long: an MQTT session's last words (NDEATH, `offline`) and its
// DISCONNECT leave within it, or the socket is closed anyway.
inline constexpr std::chrono::milliseconds output_stop_deadline{500};

class Output {
  public:
    virtual ~Output() = default;

    // What the reload's summary calls its section: "Modbus settings", "HTTP", "MQTT", …
    virtual std::string_view name() const = 0;
    // Starts serving the configuration's section for `links`, which are running.
    virtual Result<> start(const config::GatewayConfig& config, const Links& links) = 0;
    // A reload, in two steps so that nothing changes unless every output can take the new
    // configuration: prepare() may fail (an address in use, a directory refused) and changes
    // nothing that runs; abandon() lets go of what prepare() made when another output's failed;
    // apply() takes the new configuration and the links running now, and says whether its section
    // changed.
    virtual Result<> prepare(const config::GatewayConfig& next) = 0;
    virtual void abandon() {}
    virtual bool apply(const config::GatewayConfig& next, const Links& links) = 0;
    // The end: with a deadline, orderly (what is in flight finishes within it, then `done`); with
    // none, at once.
    virtual void stop(std::chrono::milliseconds deadline, std::function<void()> done) = 0;
    // What it shows: its families of /metrics, and its members of /api/v1/state.
    virtual void metrics(Exposition& out) const = 0;
    virtual void state(Json& out) const = 0;
};

using Outputs = std::vector<std::shared_ptr<Output>>;

}  // namespace ioport::daemon
