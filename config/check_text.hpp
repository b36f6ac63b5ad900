// What `ioportd --check-config` prints of a valid configuration: the Modbus front, TLS, HTTP,
// Sparkplug and its store, plain MQTT, the life-cycle settings, each link and its modules with
// what their names, units and scales are beyond the defaults, and every warning.
#pragma once

#include <string>

#include "config/gateway_config.hpp"

namespace ioport::config {

std::string check_config_text(const GatewayConfig& config);

}  // namespace ioport::config
