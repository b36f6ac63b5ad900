// The HTTP side's routes (gateway.md §5.4, §7.1) as a pure function of the request line and its
// Host: which page a method and target ask for, or the status that refuses them. GET and HEAD
// are routed to the pages; POST to /api/v1/write alone, and only where writes are served.
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
    write,    // POST /api/v1/write
};
enum class MapFormat { html, csv, markdown };

// The content type of every plain-text answer: health, refusals, errors.
inline constexpr std::string_view text_plain = "text/plain; charset=utf-8";

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
    std::string allow{};  // of a 405: the methods the path takes
    friend bool operator==(const Refusal&, const Refusal&) = default;
};

// What the router reads of a request.
struct Request {
    std::string_view method;
    std::string_view target;
    unsigned version = 11;  // 10: HTTP/1.0, 11: HTTP/1.1
    std::size_t hosts = 0;  // how many Host fields it has
    std::string_view host;  // the first one's value
    bool writes = false;    // POST /api/v1/write is served (http.web_config_file is given)
};

// The method and target alone.
Expected<Route, Refusal> route(std::string_view method, std::string_view target,
                               bool writes = false);
// The Host alone. Against DNS rebinding (a web page whose own name comes to resolve to this
// server, so that a browser reads the answers for it), the Host, port aside, must be an IP
// literal, localhost or one of `names` (the machine's host name and http.server_names; letter
// case aside, and one trailing dot), else 421. Without a Host, HTTP/1.1 is 400 (RFC 9112 §3.2)
// and HTTP/1.0 is served: browsers always send one, so such a request is no rebinding. Several
// Host fields, or one that is not host[:port], are 400.
std::optional<Refusal> host_refusal(const Request& request, std::span<const std::string> names);
// The Host first, then the method and target.
Expected<Route, Refusal> route(const Request& request, std::span<const std::string> names);

// Whether a request's Origin header, if any, is the origin of the page it came from: the scheme
// this server speaks and the Host it was asked by (a browser sends both as the address bar
// shows them). A browser sends Origin with every POST: a page of another origin cannot forge it.
// Clients other than browsers send none, and are not a page's.
bool same_origin(std::string_view origin, bool tls, std::string_view host);

// The body of POST /api/v1/write (gateway.md §7.1): {"link", "module", "point", "value"}, every
// member a string but the value, a JSON string, number or boolean in the words of a plain MQTT
// set (§6.3), as text. Fails saying what is wrong: not JSON, a member missing, of the wrong type,
// or unknown.
struct WriteBody {
    std::string link;
    std::string module;
    std::string point;
    std::string value;
    friend bool operator==(const WriteBody&, const WriteBody&) = default;
};
Expected<WriteBody, std::string> parse_write_body(std::string_view body);

// The value of `name` in a query string ("a=1&format=csv"), percent-decoded, "+" as a space;
// nullopt when absent; an error when its escapes are malformed.
Expected<std::optional<std::string>, std::string> query_value(std::string_view query,
                                                              std::string_view name);

}  // namespace ioport::daemon
