#include "config/loader.hpp"

#include "config/tls_files.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 8> tls_keys{"listen",       "certificate", "key",
                                                   "client_ca",    "client_crl",  "max_handshakes",
                                                   "default_role", "roles"};
constexpr std::array<std::string_view, 2> role_keys{"units", "access"};
constexpr std::array<std::pair<std::string_view, modbus_security::Access>, 2> accesses{
    {{"read", modbus_security::Access::read}, {"read_write", modbus_security::Access::read_write}}};

}  // namespace

void Loader::read_tls(const Entry& entry, std::optional<TlsSettings>& tls) {
    if (entry.value.IsNull()) return;  // "tls:" alone: no listen, so off
    const auto settings =
        mapping(entry, "modbus.tls", tls_keys, "{ listen: \"0.0.0.0:802\", certificate: ... }");
    if (!settings) return;
    const Fields& f = *settings;
    if (f.find("listen") == nullptr) return;  // absent = off (gateway.md §5.6)
    TlsSettings t;
    Endpoint listen{t.listen_host, t.listen_port};
    if (read(f, "listen", "host:port", listen,
             [](const YAML::Node& value) { return parse_listen(value.Scalar()); })) {
        t.listen_host = listen.host;
        t.listen_port = listen.port;
    }
    read_tls_files(f, t);
    read(f, "max_handshakes", "a number 1..1024", t.max_handshakes, integer(1, 1024));
    read_roles(f, t);
    read(f, "default_role", "a role name, or \"\" for none", t.default_role, text_value);
    if (!t.default_role.empty() && !t.roles.contains(t.default_role) && f.find("roles") != nullptr)
        add(f.line_of("default_role"), f.key("default_role"),
            fmt::format("'{}' is not one of the roles: give one of {}, or \"\" for none",
                        t.default_role, modbus_security::names(t.roles)));
    tls = std::move(t);
}

void Loader::read_tls_files(const Fields& f, TlsSettings& t) {
    require(f, "certificate", "the server's certificate (PEM), e.g. /etc/ioportd/tls/server.pem");
    require(f, "key",
            "the server certificate's private key (PEM), e.g. /etc/ioportd/tls/server.key");
    require(
        f, "client_ca",
        "the CA that signs the clients' certificates (PEM), e.g. /etc/ioportd/tls/client-ca.pem");
    const auto file = [&](std::string_view name, std::string& path, std::string& pem, auto reader) {
        if (!read(f, name, "a file's path", path, text_value)) return false;
        auto text = reader(path);
        if (!text) {
            add(f.line_of(name), f.key(name), std::move(text).error());
            return false;
        }
        pem = *std::move(text);
        return true;
    };
    const bool certificate =
        file("certificate", t.certificate, t.certificate_pem, read_certificates);
    const bool key = file("key", t.key, t.key_pem, read_private_key);
    const bool client_ca = file("client_ca", t.client_ca, t.client_ca_pem, read_certificates);
    if (client_ca)
        file("client_crl", t.client_crl, t.client_crl_pem,
             [&](const std::string& path) { return read_crl(path, t.client_ca_pem, t.client_ca); });
    if (certificate && key)
        if (auto pair = check_key_pair(t.certificate_pem, t.key_pem, t.key); !pair)
            add(f.line_of("key"), f.key("key"), std::move(pair).error());
}

void Loader::read_roles(const Fields& f, TlsSettings& t) {
    constexpr std::string_view example =
        "{ operator: { units: all, access: read_write }, viewer: { units: all, access: read } }";
    const Entry* entry = f.find("roles");
    if (entry == nullptr) {
        require(f, "roles", fmt::format("the roles clients may have, e.g. roles: {}", example));
        return;
    }
    if (!entry->value.IsMap() || entry->value.size() == 0) {
        add(entry->line, f.key("roles"),
            fmt::format("expected a mapping of role names such as {}, found {}", example,
                        entry->value.IsMap() ? "an empty mapping" : kind(entry->value)));
        return;
    }
    for (const auto& pair : entry->value) {
        const int line = line_of(pair.first);
        const std::string name = pair.first.IsScalar() ? pair.first.Scalar() : "";
        const std::string path = fmt::format("{}.{}", f.key("roles"), name);
        if (name.empty() || name.size() > modbus_security::max_role_length) {
            add(line, f.key("roles"),
                fmt::format("a role is a name of 1..{} characters",
                            modbus_security::max_role_length));
            continue;
        }
        if (t.roles.contains(name)) {
            add(line, path, "duplicate role");
            continue;
        }
        if (auto role = read_role({pair.second, line}, path)) t.roles.emplace(name, *role);
    }
}

std::optional<modbus_security::Role> Loader::read_role(const Entry& entry,
                                                       const std::string& path) {
    const auto settings = mapping(entry, path, role_keys, "{ units: all, access: read }");
    if (!settings) return std::nullopt;
    const Fields& f = *settings;
    modbus_security::Role role;
    require(f, "units", "all, or a list of unit ids such as [1, 2]");
    require(f, "access", "read or read_write");
    const std::size_t errors = errors_.size();
    read(f, "access", "read or read_write", role.access, choice<modbus_security::Access>(accesses));
    if (const Entry* units = f.find("units")) read_role_units(*units, path, role);
    if (errors_.size() != errors) return std::nullopt;
    return role;
}

void Loader::read_role_units(const Entry& entry, const std::string& path,
                             modbus_security::Role& role) {
    const std::string key = path + ".units";
    if (entry.value.IsScalar() && entry.value.Scalar() == "all" && !quoted(entry.value)) {
        role.units.set();
        return;
    }
    if (!entry.value.IsSequence() || entry.value.size() == 0) {
        add(entry.line, key,
            fmt::format("expected all, or a list of unit ids such as [1, 2], found {}",
                        entry.value.IsSequence() ? "an empty list" : kind(entry.value)));
        return;
    }
    std::size_t index = 0;
    for (const auto& item : entry.value) {
        const std::string item_key = fmt::format("{}[{}]", key, index++);
        const int line = std::max(line_of(item), entry.line);
        auto unit_id =
            item.IsScalar()
                ? integer(1, max_unit_id)(item)
                : Parsed<int>(Unexpected(fmt::format("expected a unit id, found {}", kind(item))));
        if (!unit_id) {
            add(line, item_key, std::move(unit_id).error());
            continue;
        }
        role.units.set(static_cast<std::size_t>(*unit_id));
        role_units_.push_back({*unit_id, line, item_key});
    }
}

// A unit no link has is a typing error: the role would grant nothing there.
void Loader::check_role_units(const GatewayConfig& config) {
    for (const auto& unit : role_units_) {
        if (std::ranges::any_of(
                config.links, [&](const LinkConfig& link) { return link.unit_id == unit.unit_id; }))
            continue;
        add(unit.line, unit.key,
            fmt::format("no link has unit id {}: give the unit_id of one of the links",
                        unit.unit_id));
    }
}

}  // namespace ioport::config::detail
