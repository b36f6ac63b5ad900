// Modbus/TCP Security's authorisation (gateway.md §5.6) as pure functions: the role extension's
// bytes, the rights a certificate gets, and the decision for one request.
#include <gtest/gtest.h>

#include <cstdint>
#include <vector>

#include "protocol/modbus_security.hpp"

namespace ioport::modbus_security {
namespace {

using Bytes = std::vector<std::uint8_t>;
using Kind = CertificateRole::Kind;

TEST(ModbusSecurityRole, IsTheUtf8StringOfTheExtension) {
    // 0C = UTF8String, 08 = length, then "operator": what openssl writes for
    // 1.3.6.1.4.1.50316.802.1=ASN1:UTF8String:operator.
    const Bytes operator_role{0x0C, 0x08, 'o', 'p', 'e', 'r', 'a', 't', 'o', 'r'};
    EXPECT_EQ(parse_role(operator_role).value(), "operator");
    // UTF-8 beyond ASCII: "Bediener-ü" (ü = C3 BC).
    const Bytes german{0x0C, 0x0B, 'B', 'e', 'd', 'i', 'e', 'n', 'e', 'r', '-', 0xC3, 0xBC};
    EXPECT_EQ(parse_role(german).value(), "Bediener-\xC3\xBC");
    // A long form length: 81 80 = 128 bytes.
    Bytes long_role{0x0C, 0x81, 0x80};
    long_role.resize(3 + 128, 'r');
    EXPECT_EQ(parse_role(long_role).value(), std::string(128, 'r'));
}

TEST(ModbusSecurityRole, WhatIsNotARole) {
    const auto refused = [](const Bytes& der, std::string_view fragment) {
        const auto role = parse_role(der);
        ASSERT_FALSE(role) << *role;
        EXPECT_NE(role.error().find(fragment), std::string::npos) << role.error();
    };
    refused({}, "not a DER-encoded ASN.1 UTF8String");
    // 13 = PrintableString: the specification says UTF8String.
    refused({0x13, 0x02, 'o', 'p'}, "not a DER-encoded ASN.1 UTF8String");
    // 0C 05 but only two bytes follow.
    refused({0x0C, 0x05, 'o', 'p'}, "not a DER-encoded");
    refused({0x0C, 0x02, 'o', 'p', 0x00}, "1 bytes after the UTF8String");
    refused({0x0C, 0x00}, "empty");
    // C3 alone starts a two-byte sequence that never ends.
    refused({0x0C, 0x02, 'o', 0xC3}, "not valid UTF-8");
    refused({0x0C, 0x03, 'o', '\n', 'p'}, "control characters");
    Bytes too_long{0x0C, 0x82, 0x01, 0x00};  // 256 bytes
    too_long.resize(4 + 256, 'r');
    refused(too_long, "256 bytes long, more than 255");
}

Role role(Access access, std::initializer_list<int> units = {}) {
    Role r;
    r.access = access;
    if (units.size() == 0) r.units.set();
    for (const int unit : units)
        r.units.set(static_cast<std::size_t>(unit));
    return r;
}

const Roles roles{{"operator", role(Access::read_write)},
                  {"viewer", role(Access::read)},
                  {"line2", role(Access::read_write, {2})}};

TEST(ModbusSecurityRights, FromTheCertificateOrTheDefaultRoleNeverAFallback) {
    const auto from_certificate = rights_of({Kind::valid, "viewer"}, "operator", roles);
    EXPECT_EQ(from_certificate.role, "viewer");
    ASSERT_TRUE(from_certificate.grants);
    EXPECT_EQ(from_certificate.grants->access, Access::read);
    EXPECT_EQ(from_certificate.why, "role viewer from the certificate, read");

    const auto by_default = rights_of({Kind::absent, ""}, "viewer", roles);
    EXPECT_EQ(by_default.role, "viewer");
    EXPECT_TRUE(by_default.grants);
    EXPECT_EQ(by_default.why, "role viewer default_role (no role in the certificate), read");

    const auto none = rights_of({Kind::absent, ""}, "", roles);
    EXPECT_EQ(none.role, "");
    EXPECT_FALSE(none.grants);
    EXPECT_EQ(none.why, "no role in the certificate and no default_role: no rights");

    // A role nobody configured gets nothing, not the default role.
    const auto unknown = rights_of({Kind::valid, "admin"}, "viewer", roles);
    EXPECT_EQ(unknown.role, "admin");
    EXPECT_FALSE(unknown.grants);
    EXPECT_EQ(unknown.why, "role admin from the certificate is not configured: no rights");

    const auto malformed = rights_of({Kind::malformed, "the role is empty"}, "viewer", roles);
    EXPECT_FALSE(malformed.grants);
    EXPECT_EQ(malformed.why, "malformed role extension (the role is empty): no rights");
}

TEST(ModbusSecurityPermits, ReadsWritesAndUnits) {
    const auto rights = [](const char* name) { return rights_of({Kind::valid, name}, "", roles); };
    for (const std::uint8_t read : Bytes{0x01, 0x02, 0x03, 0x04, 0x2B, 0x08, 0x11}) {
        EXPECT_TRUE(permits(rights("operator"), 1, read)) << int(read);
        EXPECT_TRUE(permits(rights("viewer"), 247, read)) << int(read);
        EXPECT_FALSE(permits(rights("admin"), 1, read)) << int(read);
    }
    for (const std::uint8_t write : Bytes{0x05, 0x06, 0x0F, 0x10, 0x16, 0x17}) {
        EXPECT_TRUE(is_write(write));
        EXPECT_TRUE(permits(rights("operator"), 1, write)) << int(write);
        EXPECT_FALSE(permits(rights("viewer"), 1, write)) << int(write);
        EXPECT_FALSE(permits(rights("admin"), 1, write)) << int(write);
    }
    EXPECT_TRUE(permits(rights("line2"), 2, 0x06));
    EXPECT_FALSE(permits(rights("line2"), 1, 0x03));
    EXPECT_FALSE(permits(rights("line2"), 3, 0x06));
    EXPECT_FALSE(permits(rights("operator"), -1, 0x03));
    EXPECT_FALSE(permits(rights("operator"), 256, 0x03));
}

}  // namespace
}  // namespace ioport::modbus_security
