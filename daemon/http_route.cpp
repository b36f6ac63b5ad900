#include "daemon/http_route.hpp"

#include <array>
#include <optional>

#include <fmt/format.h>

namespace ioport::daemon {
namespace {

struct Path {
    std::string_view path;
    Page page;
};
constexpr std::array<Path, 6> paths{{{"/", Page::status},
                                     {"/api/v1/state", Page::state},
                                     {"/api/v1/trends", Page::trends},
                                     {"/metrics", Page::metrics},
                                     {"/healthz", Page::health},
                                     {"/map", Page::map}}};

constexpr std::string_view index_hint =
    "pages here: / (status), /api/v1/state, /api/v1/trends, /metrics, /healthz, /map";

std::optional<int> hex_digit(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return std::nullopt;
}

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

}  // namespace

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

Expected<Route, Refusal> route(std::string_view method, std::string_view target) {
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
    const bool head = method == "HEAD";
    if (method != "GET" && !head)
        return Unexpected(Refusal{405, "this server is read-only: use GET (or HEAD)"});
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
        return Unexpected(Refusal{400, fmt::format("format: '{}' is not html, csv or md", format)});
    return route;
}

}  // namespace ioport::daemon
