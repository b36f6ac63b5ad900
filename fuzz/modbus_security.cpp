// Fuzz target: Modbus/TCP Security's authorisation (protocol/modbus_security.hpp): the role
// extension's bytes as any client certificate signed by the plant's CA may carry them, and the
// decision for a request.
//
// Input: byte 0 the unit id of the request, byte 1 its function code, byte 2 picks the default
// role (0 none, 1 operator, 2 viewer, else line2); the rest is the extension's value (DER).
//
// Invariants, from gateway.md §5.6 rather than from the code under test:
// - a parsed role is non-empty UTF-8 of at most 255 bytes without control characters, and a
//   UTF8String of exactly those bytes parses to it again;
// - a certificate role that is not configured, or a malformed extension, grants nothing, whatever
//   the default role;
// - nothing granted permits nothing; read access never permits a write; a unit not in the role
//   is never permitted.
#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "fuzz/fuzz.hpp"
#include "protocol/modbus_security.hpp"

namespace ioport::fuzz {
namespace {

using modbus_security::Access;
using modbus_security::CertificateRole;

modbus_security::Roles configured_roles() {
    modbus_security::Roles roles;
    roles["operator"].access = Access::read_write;
    roles["operator"].units.set();
    roles["viewer"].access = Access::read;
    roles["viewer"].units.set();
    roles["line2"].access = Access::read_write;
    roles["line2"].units.set(2);
    return roles;
}

bool valid_utf8_text(const std::string& text) {
    std::size_t i = 0;
    while (i < text.size()) {
        const auto byte = static_cast<unsigned char>(text[i]);
        if (byte < 0x20 || byte == 0x7F) return false;
        const std::size_t length = byte < 0x80         ? 1
                                   : (byte >> 5) == 6  ? 2
                                   : (byte >> 4) == 14 ? 3
                                   : (byte >> 3) == 30 ? 4
                                                       : 0;
        if (length == 0 || i + length > text.size()) return false;
        for (std::size_t k = 1; k < length; ++k)
            if ((static_cast<unsigned char>(text[i + k]) >> 6) != 2) return false;
        i += length;
    }
    return true;
}

// GCC 12 warns of a vector's insert of a string's bytes (a false stringop-overflow): built as a
// string, then copied.
std::vector<std::uint8_t> utf8_string(const std::string& text) {
    std::string der(1, '\x0C');
    if (text.size() >= 0x80) der.push_back('\x81');
    der.push_back(static_cast<char>(text.size()));
    der.append(text);
    return {der.begin(), der.end()};
}

void check_decision(const modbus_security::Rights& rights, int unit, std::uint8_t function) {
    const bool permitted = modbus_security::permits(rights, unit, function);
    if (!rights.grants) {
        check(!permitted, "no rights permit nothing");
        return;
    }
    if (!rights.grants->units.test(static_cast<std::size_t>(unit)))
        check(!permitted, "a unit outside the role is never permitted");
    if (rights.grants->access == Access::read && modbus_security::is_write(function))
        check(!permitted, "read access never permits a write");
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace ioport;
    using namespace ioport::fuzz;
    if (size < 3) return 0;
    static const auto roles = configured_roles();
    const int unit = data[0];
    const std::uint8_t function = data[1];
    static constexpr std::array<const char*, 4> defaults{"", "operator", "viewer", "line2"};
    const char* default_role = defaults[std::min<std::size_t>(data[2], 3)];
    const std::span<const std::uint8_t> der(data + 3, size - 3);

    const auto role = modbus_security::parse_role(der);
    CertificateRole certificate;
    if (role) {
        check(!role->empty() && role->size() <= modbus_security::max_role_length,
              "a role is 1..255 bytes");
        check(valid_utf8_text(*role), "a role is UTF-8 without control characters");
        const auto again = modbus_security::parse_role(utf8_string(*role));
        check(again && *again == *role, "the role's own UTF8String parses to it");
        certificate = {CertificateRole::Kind::valid, *role};
    } else {
        check(!role.error().empty(), "a refusal says why");
        certificate = {CertificateRole::Kind::malformed, role.error()};
    }
    const auto rights = modbus_security::rights_of(certificate, default_role, roles);
    if (!role || !roles.contains(*role)) check(!rights.grants, "no fallback to the default role");
    check_decision(rights, unit, function);
    check_decision(modbus_security::rights_of({}, default_role, roles), unit, function);
    return 0;
}
