// The HTTP side's routes (gateway.md §5.4) as a pure function of the request line and its Host:
// which page a method and target ask for, or the status that refuses them. Read-only by
// construction: only GET and HEAD are ever routed.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "protocol/expected.hpp"

namespace ioport::daemon {

enum class Page {
    status,   // GET /: the live status page
    script,   // GET /app.js: the status page's script
    style,    // GET /app.css: the status page's style (the map's too)
    icon,     // GET /icon.svg: the status page's icon
    state,    // GET /api/v1/state
    trends,   // GET /api/v1/trends
    metrics,  // GET /metrics
    health,   // GET /healthz
    map,      // GET /map[?format=html|csv|md]
};
enum class MapFormat { html, csv, markdown };

struct Route {
    Page page = Page::status;
    MapFormat format = MapFormat::html;  // of Page::map
    bool head = false;                   // HEAD: the headers of GET, no body
    friend bool operator==(const Route&, const Route&) = default;
};

struct Refusal {
    // 400 bad target, query or Host; 404 no such page; 405 not GET or HEAD; 421 a Host this
    // server does not answer for
    unsigned status = 404;
    std::string message;  // the response body: what is wrong and what to do
    friend bool operator==(const Refusal&, const Refusal&) = default;
};

// What the router reads of a request.
struct Request {
    std::string_view method;
    std::string_view target;
    unsigned version = 11;  // 10: HTTP/1.0, 11: HTTP/1.1
    std::size_t hosts = 0;  // how many Host fields it has
    std::string_view host;  // the first one's value
};

// The method and target alone.
Expected<Route, Refusal> route(std::string_view method, std::string_view target);
// The Host first, then the method and target. Against DNS rebinding (a web page whose own name
// comes to resolve to this server, so that a browser reads the answers for it), the Host, port
// aside, must be an IP literal, localhost or one of `names` (the machine's host name and
// http.server_names; letter case aside, and one trailing dot), else 421. Without a Host,
// HTTP/1.1 is 400 (RFC 9112 §3.2) and HTTP/1.0 is served: browsers always send one, so such a
// request is no rebinding. Several Host fields, or one that is not host[:port], are 400.
Expected<Route, Refusal> route(const Request& request, std::span<const std::string> names);

// The value of `name` in a query string ("a=1&format=csv"), percent-decoded, "+" as a space;
// nullopt when absent; an error when its escapes are malformed.
Expected<std::optional<std::string>, std::string> query_value(std::string_view query,
                                                              std::string_view name);

}  // namespace ioport::daemon
