// The pages of the HTTP side (gateway.md §5.4), rendered from the running gateway on each
// request: nothing is kept for them but the counters, events and trends that the links and the
// outputs keep anyway. Every output shows itself through the seam (core/output.hpp): this room
// includes none of theirs.
#pragma once

#include <string>

#include "config/gateway_config.hpp"
#include "daemon/core/events.hpp"
#include "daemon/core/link_scheduler.hpp"
#include "daemon/core/output.hpp"
#include "daemon/http/http_server.hpp"
#include "daemon/http/process_stats.hpp"

namespace ioport::daemon {

// What the pages render: the running gateway's parts, read-only, for the one request being
// answered (the gateway owns them all; a reload may replace them between requests).
struct GatewayView {
    const config::GatewayConfig& config;
    const Links& links;
    const Outputs& outputs;  // each shows its families and state members, in this order
    const EventLog& events;
    std::chrono::system_clock::time_point started;
};

// The status page: daemon/http/status_page/index.html, app.js, app.css and icon.svg, embedded
// at build time.
extern const std::string_view status_page_html;
extern const std::string_view status_page_js;
extern const std::string_view status_page_css;
extern const std::string_view status_page_svg;

// A page (not Page::write) for `caller`.
HttpResponse render_page(const GatewayView& gateway, const Route& route, const Caller& caller);

std::string render_metrics(const GatewayView& gateway, const ProcessStats& process);
std::string render_state(const GatewayView& gateway, const Caller& caller = {});
std::string render_trends(const GatewayView& gateway);
// The register map of the running configuration, as --print-map prints it, or as an HTML page.
std::string render_map(const config::GatewayConfig& config, MapFormat format);

}  // namespace ioport::daemon
