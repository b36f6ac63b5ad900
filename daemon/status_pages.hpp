// The pages of the HTTP side (gateway.md §5.4), rendered from the running gateway on each
// request: nothing is kept for them but the counters, events and trends that the links and the
// Modbus server keep anyway.
#pragma once

#include <string>

#include "daemon/gateway.hpp"
#include "daemon/http_server.hpp"
#include "daemon/process_stats.hpp"

namespace ioport::daemon {

// The status page: daemon/status_page/index.html, embedded at build time.
extern const std::string_view status_page_html;

HttpResponse render_page(const Gateway& gateway, const Route& route);

std::string render_metrics(const Gateway& gateway, const ProcessStats& process);
std::string render_state(const Gateway& gateway);
std::string render_trends(const Gateway& gateway);
// The register map of the running configuration, as --print-map prints it, or as an HTML page.
std::string render_map(const config::GatewayConfig& config, MapFormat format);

// "online", "no answer", "bad answer", "not polled yet", "not configured".
std::string_view status_text(gateway::ModuleStatus status);

}  // namespace ioport::daemon
