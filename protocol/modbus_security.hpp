// Modbus/TCP Security's authorisation (gateway.md §5.6) as pure functions: the role a client
// certificate names, what a configured role grants, and whether one request is within it. The
// TLS side (daemon/modbus_tls) reads the certificate; these decide.
#pragma once

#include <bitset>
#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "protocol/expected.hpp"

namespace ioport::modbus_security {

// The X.509v3 extension of the Modbus/TCP Security specification that carries the client's role,
// an ASN.1 UTF8String.
inline constexpr std::string_view role_oid = "1.3.6.1.4.1.50316.802.1";
// A role name longer than this is not a role anyone configured.
inline constexpr std::size_t max_role_length = 255;

enum class Access { read, read_write };
std::string_view to_string(Access access);  // "read", "read_write"

struct Role {
    std::bitset<256> units;  // by unit id; every bit set for `units: all`
    Access access = Access::read;
    friend bool operator==(const Role&, const Role&) = default;
};
using Roles = std::map<std::string, Role, std::less<>>;
// "operator, viewer": for messages.
std::string names(const Roles& roles);

// The role in the extension's value (the DER of a UTF8String, nothing after it), or why there is
// none: not DER, another type, not UTF-8, control characters, empty or too long.
Expected<std::string, std::string> parse_role(std::span<const std::uint8_t> der);

// What the certificate said of the role.
struct CertificateRole {
    enum class Kind { absent, valid, malformed } kind = Kind::absent;
    std::string text;  // the role (valid) or what is wrong with the extension (malformed)
};

// What a client may do, decided once when it connects and kept until it closes.
struct Rights {
    std::string role;            // its name; empty: none
    std::optional<Role> grants;  // nullopt: nothing at all
    std::string why;             // for the connect log: "role operator from the certificate"
};

// A certificate without the extension gets `default_role` ("" = none); a malformed one, or a role
// not in `roles`, gets nothing: no fallback.
Rights rights_of(const CertificateRole& certificate, std::string_view default_role,
                 const Roles& roles);

// Whether a request of `function` to the link of `unit_id` is within `rights`: any function of a
// listed unit for read_write, all but the writes for read.
bool permits(const Rights& rights, int unit_id, std::uint8_t function);

// FC 05, 06, 15, 16, 22 and 23 change outputs; every other function reads (or is refused later as
// unsupported).
bool is_write(std::uint8_t function);

}  // namespace ioport::modbus_security
