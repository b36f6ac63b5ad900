#include "config/loader.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 6> http_keys{"listen",          "allow",     "server_names",
                                                    "web_config_file", "operators", "ipv6_prefix"};

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
    read_web(f, *http);
    read(f, "ipv6_prefix", "a prefix length 64..128", http->ipv6_prefix, integer(64, 128));
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

// http.web_config_file and http.operators (gateway.md §7.1). The web configuration's own errors
// name its file; an operator must be one of its users, or the name grants nothing.
void Loader::read_web(const Fields& f, HttpSettings& http) {
    std::string path;
    if (read(f, "web_config_file", "a file's path", path, text_value) && !path.empty()) {
        const auto main_file = std::exchange(file_, path);
        http.web = read_web_config(path);
        file_ = main_file;
    }
    read_list(f, "operators", "a list of user names such as [\"alice\"]", "a user name", user_name,
              http.operators);
    const Entry* operators = f.find("operators");
    if (operators == nullptr || http.operators.empty()) return;
    if (f.find("web_config_file") == nullptr) {
        add(operators->line, f.key("operators"),
            "names users, and there are none without http.web_config_file: add one with "
            "basic_auth_users (or client certificates), or remove operators");
        return;
    }
    if (!http.web) return;  // its errors are told
    // Without passwords a verified client certificate's CN is the user: any name may be one.
    if (http.web->users.empty()) return;
    for (const auto& name : http.operators)
        if (!http.web->users.contains(name))
            add(operators->line, f.key("operators"),
                fmt::format("'{}' is not one of basic_auth_users in {}: add the user there, or "
                            "remove the name",
                            printable(name), http.web->path));
}

void Loader::read_server_names(const Fields& f, std::vector<std::string>& names) {
    read_list(f, "server_names", "a list of host names such as [\"gateway.plant.example\"]",
              "a host name", server_name, names);
}

}  // namespace ioport::config::detail
