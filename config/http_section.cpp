#include "config/loader.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 3> http_keys{"listen", "allow", "server_names"};

// http.server_names: what a Host header names, as DNS spells it; no scheme, port or wildcard.
Parsed<std::string> server_name(const std::string& name) {
    constexpr std::size_t max_length = 253;
    const auto dns = [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
               c == '-' || c == '.' || c == '_';
    };
    if (name.empty() || name.size() > max_length || !std::ranges::all_of(name, dns))
        return Unexpected(fmt::format(
            "'{}' is not a host name: give one of 1..{} letters, digits, '-', '_' and '.', as a "
            "browser's address bar names this server, e.g. gateway.plant.example (no scheme, port "
            "or wildcard)",
            printable(name), max_length));
    return name;
}

}  // namespace

void Loader::read_http(const Entry& entry, std::optional<HttpSettings>& http) {
    http = HttpSettings{};
    if (entry.value.IsNull()) return;  // "http:" alone: every default
    const auto settings = mapping(entry, "http", http_keys, "{ listen: \"127.0.0.1:8502\" }");
    if (!settings) return;
    const Fields& f = *settings;
    read_allow(f, http->allow);
    read_server_names(f, http->server_names);
    Endpoint listen{http->listen_host, http->listen_port};
    const Entry* off = f.find("listen");
    if (off != nullptr && off->value.IsScalar() && off->value.Scalar().empty()) {
        http.reset();
        return;
    }
    if (read(f, "listen", "host:port, or \"\" for off", listen,
             [](const YAML::Node& value) { return parse_listen(value.Scalar()); })) {
        http->listen_host = listen.host;
        http->listen_port = listen.port;
    }
}

void Loader::read_server_names(const Fields& f, std::vector<std::string>& names) {
    read_list(f, "server_names", "a list of host names such as [\"gateway.plant.example\"]",
              "a host name", server_name, names);
}

}  // namespace ioport::config::detail
