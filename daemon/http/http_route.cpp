#include "daemon/http/http_route.hpp"

#include <algorithm>
#include <array>
#include <optional>

#include <fmt/format.h>
#include <boost/asio/ip/address.hpp>

#include "protocol/error.hpp"
#include "protocol/hex.hpp"
#include "protocol/json_reader.hpp"

namespace ioport::daemon {
namespace {

struct Path {
    std::string_view path;
    Page page;
};
constexpr std::array<Path, 10> paths{{{"/", Page::status},
                                      {"/app.js", Page::script},
                                      {"/app.css", Page::style},
                                      {"/icon.svg", Page::icon},
                                      {"/api/v1/state", Page::state},
                                      {"/api/v1/trends", Page::trends},
                                      {"/metrics", Page::metrics},
                                      {"/healthz", Page::health},
                                      {"/map", Page::map},
                                      {"/api/v1/write", Page::write}}};

constexpr std::string_view index_hint =
    "pages here: / (status), /api/v1/state, /api/v1/trends, /metrics, /healthz, /map; "
    "POST /api/v1/write";

// Percent-decoding of a query component; nullopt for a malformed escape.
std::optional<std::string> decoded(std::string_view text) {
    std::string out;
    out.reserve(text.size());
    for (std::size_t i = 0; i < text.size(); ++i) {
        if (text[i] == '+') {
            out += ' ';
        } else if (text[i] != '%') {
            out += text[i];
        } else {
            if (i + 2 >= text.size()) return std::nullopt;
            const auto high = hex_digit(text[i + 1]);
            const auto low = hex_digit(text[i + 2]);
            if (!high || !low) return std::nullopt;
            out += static_cast<char>(*high * 16 + *low);
            i += 2;
        }
    }
    return out;
}

char lower(char c) {
    return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c;
}

// Host names compare without regard to letter case, or to the root's trailing dot.
bool same_name(std::string_view a, std::string_view b) {
    if (a.ends_with('.')) a.remove_suffix(1);
    if (b.ends_with('.')) b.remove_suffix(1);
    return std::ranges::equal(a, b, {}, lower, lower);
}

// RFC 3986: port = *DIGIT, after a colon, or nothing at all.
bool port_or_nothing(std::string_view rest) {
    if (rest.empty()) return true;
    return rest.front() == ':' &&
           std::ranges::all_of(rest.substr(1), [](char c) { return c >= '0' && c <= '9'; });
}

// Asio's parsers read a C string, which a NUL would cut short; and a scope ("%eth0") would make
// them look the interface up, where browsers never send one.
bool ip_literal(std::string_view text, bool v6) {
    if (text.find_first_of(std::string_view("%\0", 2)) != std::string_view::npos) return false;
    boost::system::error_code ec;
    if (v6)
        boost::asio::ip::make_address_v6(std::string(text), ec);
    else
        boost::asio::ip::make_address_v4(std::string(text), ec);
    return !ec;
}

constexpr std::string_view misdirected =
    "this server does not answer for that host name, which guards against DNS rebinding: use "
    "its IP address or localhost, or add the name to http.server_names";

}  // namespace

std::optional<Refusal> host_refusal(const Request& request, std::span<const std::string> names) {
    if (request.hosts > 1) return Refusal{400, "more than one Host header"};
    if (request.hosts == 0) {
        if (request.version >= 11) return Refusal{400, "HTTP/1.1 requires a Host header"};
        return std::nullopt;
    }
    const auto host = request.host;
    const auto malformed = Refusal{400, "the Host header is not host[:port]"};
    if (host.starts_with('[')) {
        const auto close = host.find(']');
        if (close == std::string_view::npos || !ip_literal(host.substr(1, close - 1), true) ||
            !port_or_nothing(host.substr(close + 1)))
            return malformed;
        return std::nullopt;
    }
    const auto colon = host.find(':');
    const auto name = host.substr(0, colon);
    if (colon != std::string_view::npos && !port_or_nothing(host.substr(colon))) return malformed;
    if (ip_literal(name, false)) return std::nullopt;
    if (same_name(name, "localhost") ||
        std::ranges::any_of(names, [&](const std::string& n) { return same_name(name, n); }))
        return std::nullopt;
    return Refusal{421, std::string(misdirected)};
}

bool same_origin(std::string_view origin, bool tls, std::string_view host) {
    if (origin.empty()) return true;
    const std::string_view scheme = tls ? "https://" : "http://";
    if (origin.size() != scheme.size() + host.size()) return false;
    return std::ranges::equal(origin.substr(0, scheme.size()), scheme, {}, lower) &&
           same_name(origin.substr(scheme.size()), host);
}

Expected<WriteBody, std::string> parse_write_body(std::string_view body) {
    constexpr std::string_view example =
        R"(: {"link": "hub0", "module": "dom16_0", "point": "out3", "value": "ON"})";
    const auto object = JsonObject::parse(body);
    if (!object)
        return Unexpected(fmt::format("the body is {}{}", object.error().message, example));
    for (const auto& key : object->keys())
        if (key != "link" && key != "module" && key != "point" && key != "value")
            return Unexpected(
                fmt::format("'{}' is not a member of a write{}", printable(key, 40), example));
    WriteBody write;
    for (auto [name, out] : {std::pair<std::string_view, std::string*>{"link", &write.link},
                             {"module", &write.module},
                             {"point", &write.point}}) {
        auto text = object->string(name);
        if (!text) return Unexpected(fmt::format("{}: a string is missing{}", name, example));
        *out = *std::move(text);
    }
    auto value = object->scalar_text("value");
    if (!value)
        return Unexpected(fmt::format(
            "value: a string, number or boolean is missing, as a plain MQTT set takes it{}",
            example));
    write.value = *std::move(value);
    return write;
}

Expected<std::optional<std::string>, std::string> query_value(std::string_view query,
                                                              std::string_view name) {
    while (!query.empty()) {
        const auto amp = query.find('&');
        const auto pair = query.substr(0, amp);
        query = amp == std::string_view::npos ? std::string_view() : query.substr(amp + 1);
        const auto equals = pair.find('=');
        const auto key = decoded(pair.substr(0, equals));
        if (!key || *key != name) continue;
        auto value = decoded(equals == std::string_view::npos ? std::string_view()
                                                              : pair.substr(equals + 1));
        if (!value) return Unexpected(fmt::format("{}: a malformed %-escape", name));
        return value;
    }
    return std::optional<std::string>();
}

Expected<Route, Refusal> route(std::string_view method, std::string_view target, bool writes) {
    // Origin form only ("/path?query"): a proxy's absolute form or "*" is not for this server.
    if (!target.starts_with('/'))
        return Unexpected(Refusal{400, fmt::format("the request target must be a path such as "
                                                   "/metrics; {}",
                                                   index_hint)});
    const auto question = target.find('?');
    const auto path = target.substr(0, question);
    const auto query =
        question == std::string_view::npos ? std::string_view() : target.substr(question + 1);
    const Path* found = nullptr;
    for (const auto& candidate : paths)
        if (candidate.path == path) found = &candidate;
    if (found == nullptr)
        return Unexpected(Refusal{404, fmt::format("no page at this path; {}", index_hint)});
    if (found->page == Page::write) {
        if (!writes)
            return Unexpected(Refusal{405,
                                      "this server takes no writes: an operator writes where "
                                      "http.web_config_file is given (gateway.md §7.1)",
                                      ""});
        if (method != "POST")
            return Unexpected(Refusal{405, "a write is a POST with a JSON body", "POST"});
        return Route{Page::write, MapFormat::html, false};
    }
    const bool head = method == "HEAD";
    if (method != "GET" && !head)
        return Unexpected(Refusal{405, "this page is read-only: use GET (or HEAD)", "GET, HEAD"});
    Route route{found->page, MapFormat::html, head};
    if (route.page != Page::map) return route;
    const auto value = query_value(query, "format");
    if (!value) return Unexpected(Refusal{400, value.error() + "; use html, csv or md"});
    if (!*value) return route;
    const auto& format = **value;
    if (format == "html")
        route.format = MapFormat::html;
    else if (format == "csv")
        route.format = MapFormat::csv;
    else if (format == "md")
        route.format = MapFormat::markdown;
    else
        return Unexpected(Refusal{
            400, fmt::format("format: '{}' is not html, csv or md", printable(format, 40))});
    return route;
}

Expected<Route, Refusal> route(const Request& request, std::span<const std::string> names) {
    if (auto refusal = host_refusal(request, names)) return Unexpected(*std::move(refusal));
    return route(request.method, request.target, request.writes);
}

}  // namespace ioport::daemon
