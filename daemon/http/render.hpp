// The pages of the HTTP side (gateway.md §5.4), rendered from the running gateway on each
// request: nothing is kept for them but the counters, events and trends that the links and the
// outputs keep anyway. Every output shows itself through the seam (core/output.hpp): this room
// includes none of theirs.
#pragma once

#include <cstddef>
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

// A page (not Page::write) for `caller`. `metrics_bytes`: the size of the last /metrics, which
// the next one reserves at once and updates (see render_metrics).
HttpResponse render_page(const GatewayView& gateway, const Route& route, const Caller& caller,
                         std::size_t& metrics_bytes);

// `reserve`: the text's room from the start. A scrape of a large configuration is hundreds of
// KiB; grown from nothing it doubles through every size below, past glibc's mmap and trim
// thresholds, and each scrape faulted its pages in afresh (issue 42: 332 minor faults and
// 8.8 ms a scrape of 8 × 72 named modules). Reserved at the last scrape's size, it is one
// allocation that the heap keeps between scrapes.
std::string render_metrics(const GatewayView& gateway, const ProcessStats& process,
                           std::size_t reserve = 0);
std::string render_state(const GatewayView& gateway, const Caller& caller = {});
std::string render_trends(const GatewayView& gateway);
// The register map of the running configuration, as --print-map prints it, or as an HTML page.
std::string render_map(const config::GatewayConfig& config, MapFormat format);

}  // namespace ioport::daemon
