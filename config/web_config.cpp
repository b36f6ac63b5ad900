// http.web_config_file (gateway.md §7.1): the Prometheus exporter-toolkit's web configuration,
// the file node_exporter and the other exporters take with --web.config.file, so that a file an
// operator has for an exporter works here unchanged. Its keys that ioportd does not implement are
// errors naming the key, never ignored: a setting that silently does nothing is a hole.
#include <algorithm>
#include <filesystem>

#include <fmt/ranges.h>

#include "config/loader.hpp"
#include "config/tls_files.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 4> web_keys{"tls_server_config", "http_server_config",
                                                   "basic_auth_users", "rate_limit"};
constexpr std::array<std::string_view, 13> tls_server_keys{"cert_file",
                                                           "key_file",
                                                           "client_auth_type",
                                                           "client_ca_file",
                                                           "min_version",
                                                           "max_version",
                                                           "cert",
                                                           "key",
                                                           "client_ca",
                                                           "cipher_suites",
                                                           "prefer_server_cipher_suites",
                                                           "curve_preferences",
                                                           "client_allowed_sans"};
constexpr std::array<std::string_view, 2> http_server_keys{"headers", "http2"};
// Of the format, and not done here (inline PEM, Go's cipher and curve names, SAN pinning, a rate
// limit): each is refused with what to do instead.
constexpr std::array<std::pair<std::string_view, std::string_view>, 8> not_implemented{{
    {"rate_limit", "the failure limiter of gateway.md §7.1 bounds what one address can try"},
    {"cert", "give the certificate as cert_file"},
    {"key", "give the key as key_file"},
    {"client_ca", "give the CA as client_ca_file"},
    {"cipher_suites", "ioportd's TLS 1.2 suites are ECDHE with AES-GCM or ChaCha20 only"},
    {"prefer_server_cipher_suites", "ioportd always prefers its own order"},
    {"curve_preferences", "OpenSSL's defaults are used"},
    {"client_allowed_sans", "sign the clients' certificates with a CA of their own"},
}};
// The headers the exporter-toolkit lets a file set, as it spells them.
constexpr std::array<std::string_view, 5> settable_headers{
    "Content-Security-Policy", "X-Frame-Options", "X-Content-Type-Options", "X-XSS-Protection",
    "Strict-Transport-Security"};
constexpr std::array<std::pair<std::string_view, ClientAuth>, 5> client_auths{{
    {"NoClientCert", ClientAuth::none},
    {"RequestClientCert", ClientAuth::request},
    {"RequireAnyClientCert", ClientAuth::require_any},
    {"VerifyClientCertIfGiven", ClientAuth::verify_if_given},
    {"RequireAndVerifyClientCert", ClientAuth::require_and_verify},
}};
constexpr std::array<std::pair<std::string_view, TlsVersion>, 2> tls_versions{{
    {"TLS12", TlsVersion::tls12},
    {"TLS13", TlsVersion::tls13},
}};

// "$2y$10$" and 53 characters of bcrypt's base64: what htpasswd -nBC writes.
bool bcrypt_hash(std::string_view hash) {
    const auto b64 = [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
               c == '.' || c == '/';
    };
    if (hash.size() != 60 || hash[0] != '$' || hash[1] != '2' || hash[3] != '$' || hash[6] != '$')
        return false;
    if (hash[2] != 'a' && hash[2] != 'b' && hash[2] != 'y') return false;
    const int cost = (hash[4] - '0') * 10 + (hash[5] - '0');
    if (hash[4] < '0' || hash[4] > '3' || hash[5] < '0' || hash[5] > '9' || cost < 4 || cost > 31)
        return false;
    return std::all_of(hash.begin() + 7, hash.end(), b64);
}

}  // namespace

std::optional<WebConfig> Loader::read_web_config(const std::string& path) {
    constexpr std::size_t max_web_config = std::size_t{64} << 10;
    WebConfig web;
    web.path = path;
    // It names the users who may write and holds their hashes: a file that grants rights
    // (gateway.md §5.6), which others may not read either.
    auto text = read_protected_file(path, Secrecy::secret, max_web_config);
    if (!text) {
        add(0, "", std::move(text).error());
        return std::nullopt;
    }
    YAML::Node root;
    try {
        root = YAML::Load(*text);
    } catch (const YAML::Exception& e) {
        add(e.mark.line + 1, "", fmt::format("YAML syntax error: {}", e.msg));
        return std::nullopt;
    }
    if (root.IsNull()) return web;  // an empty file: plain HTTP, no passwords, as none
    if (!root.IsMap()) {
        add(line_of(root), "", "expected a mapping with tls_server_config, basic_auth_users …");
        return std::nullopt;
    }
    const Fields top = fields(root, "", web_keys);
    refuse_unimplemented(top);
    if (const Entry* tls = top.find("tls_server_config"))
        read_web_tls(*tls, std::filesystem::path(path).parent_path(), web.tls);
    if (const Entry* server = top.find("http_server_config")) read_web_headers(*server, web);
    if (const Entry* users = top.find("basic_auth_users")) read_web_users(*users, web);
    return web;
}

void Loader::refuse_unimplemented(const Fields& f) {
    for (const auto& [name, instead] : not_implemented)
        if (f.find(name) != nullptr)
            add(f.line_of(name), f.key(name),
                fmt::format("ioportd does not implement this key of the exporter-toolkit's web "
                            "configuration, and does not ignore it: {}; remove it",
                            instead));
}

void Loader::read_web_tls(const Entry& entry, const std::filesystem::path& base,
                          std::optional<WebTlsSettings>& tls) {
    const auto settings = mapping(entry, "tls_server_config", tls_server_keys,
                                  "{ cert_file: server.crt, key_file: server.key }");
    if (!settings) return;
    const Fields& f = *settings;
    refuse_unimplemented(f);
    WebTlsSettings t;
    require(f, "cert_file",
            "the server's certificate (PEM), e.g. cert_file: /etc/ioportd/http.crt");
    require(f, "key_file", "its private key (PEM), e.g. key_file: /etc/ioportd/http.key");
    // As the exporter-toolkit takes them: a relative path is the web configuration's neighbour.
    const auto file = [&](std::string_view name, std::string& path, std::string& pem, auto reader) {
        if (!read(f, name, "a file's path", path, text_value)) return false;
        const auto full = (base / path).string();
        auto text = reader(full);
        if (!text) {
            add(f.line_of(name), f.key(name), std::move(text).error());
            return false;
        }
        path = full;
        pem = *std::move(text);
        return true;
    };
    const bool certificate = file("cert_file", t.cert_file, t.cert_pem, read_certificates);
    const bool key = file("key_file", t.key_file, t.key_pem, read_private_key);
    if (certificate && key)
        if (auto pair = check_key_pair(t.cert_pem, t.key_pem, t.key_file); !pair)
            add(f.line_of("key_file"), f.key("key_file"), std::move(pair).error());
    file("client_ca_file", t.client_ca_file, t.client_ca_pem, read_certificates);
    read(f, "client_auth_type", "a client auth type", t.client_auth,
         choice<ClientAuth>(client_auths));
    read(f, "min_version", "TLS12 or TLS13", t.min_version, choice<TlsVersion>(tls_versions));
    read(f, "max_version", "TLS12 or TLS13", t.max_version, choice<TlsVersion>(tls_versions));
    if (t.max_version < t.min_version)
        add(f.line_of("max_version"), f.key("max_version"), "is below min_version");
    const bool verifies = t.client_auth == ClientAuth::verify_if_given ||
                          t.client_auth == ClientAuth::require_and_verify;
    if (verifies && f.find("client_ca_file") == nullptr)
        add(f.line_of("client_auth_type"), f.key("client_auth_type"),
            "checks the clients' certificates against client_ca_file, which is missing: add it");
    tls = std::move(t);
}

void Loader::read_web_headers(const Entry& entry, WebConfig& web) {
    const auto settings = mapping(entry, "http_server_config", http_server_keys,
                                  "{ headers: { Strict-Transport-Security: max-age=31536000 } }");
    if (!settings) return;
    const Fields& f = *settings;
    // ioportd speaks HTTP/1.1: false says so, true asks for what it does not do.
    if (const Entry* http2 = f.find("http2"); http2 != nullptr) {
        bool on = true;
        if (read(f, "http2", "true or false", on, boolean) && on)
            add(http2->line, f.key("http2"),
                "ioportd speaks HTTP/1.1 only: write http2: false, or remove the key");
    }
    const Entry* headers = f.find("headers");
    if (headers == nullptr || headers->value.IsNull()) return;
    const std::string key = f.key("headers");
    if (!headers->value.IsMap()) {
        add(headers->line, key,
            fmt::format("expected a mapping of header names to values, found {}",
                        kind(headers->value)));
        return;
    }
    for (const auto& header : headers->value) {
        const auto name = header.first.Scalar();
        const int line = line_of(header.first);
        if (std::ranges::find(settable_headers, name) == settable_headers.end()) {
            add(line, fmt::format("{}.{}", key, printable(name)),
                fmt::format("not a header the web configuration sets: one of {}",
                            fmt::join(settable_headers, ", ")));
            continue;
        }
        const auto& value = header.second;
        if (!value.IsScalar() || value.Scalar().find_first_of("\r\n") != std::string::npos) {
            add(line, fmt::format("{}.{}", key, name), "expected a value on one line");
            continue;
        }
        // Unset if blank, as the exporter-toolkit says.
        if (!value.Scalar().empty()) web.headers.emplace_back(name, value.Scalar());
    }
}

void Loader::read_web_users(const Entry& entry, WebConfig& web) {
    if (entry.value.IsNull()) return;
    if (!entry.value.IsMap()) {
        add(entry.line, "basic_auth_users",
            fmt::format("expected a mapping of user names to bcrypt hashes, found {}",
                        kind(entry.value)));
        return;
    }
    for (const auto& user : entry.value) {
        const auto name = user.first.Scalar();
        const auto key = fmt::format("basic_auth_users.{}", printable(name));
        const int line = line_of(user.first);
        if (auto valid = user_name(name); !valid) {
            add(line, key, std::move(valid).error());
            continue;
        }
        if (!user.second.IsScalar() || !bcrypt_hash(user.second.Scalar())) {
            add(line, key,
                "expected a bcrypt hash ($2a$, $2b$ or $2y$, as htpasswd -nBC 10 writes it), not a "
                "password: make one with htpasswd -nBC 10 \"\" | tr -d ':\\n'");
            continue;
        }
        web.users.emplace(name, user.second.Scalar());
    }
}

}  // namespace ioport::config::detail
