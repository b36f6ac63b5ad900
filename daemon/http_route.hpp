// The HTTP side's routes (gateway.md §5.4) as a pure function of the request line: which page a
// method and target ask for, or the status that refuses them. Read-only by construction: only
// GET and HEAD are ever routed.
#pragma once

#include <optional>
#include <string>
#include <string_view>

#include "protocol/expected.hpp"

namespace ioport::daemon {

enum class Page {
    status,   // GET /: the live status page
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
    unsigned status = 404;  // 400 bad target or query, 404 no such page, 405 not GET or HEAD
    std::string message;    // the response body: what is wrong and what to do
    friend bool operator==(const Refusal&, const Refusal&) = default;
};

Expected<Route, Refusal> route(std::string_view method, std::string_view target);

// The value of `name` in a query string ("a=1&format=csv"), percent-decoded, "+" as a space;
// nullopt when absent; an error when its escapes are malformed.
Expected<std::optional<std::string>, std::string> query_value(std::string_view query,
                                                              std::string_view name);

}  // namespace ioport::daemon
