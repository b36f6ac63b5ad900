#include "protocol/modbus_security.hpp"

#include <algorithm>
#include <memory>

#include <fmt/format.h>

#include "protocol/openssl.hpp"

namespace ioport::modbus_security {
namespace {

// A role is written into the journal and the status page: no control characters.
bool printable(std::string_view text) {
    return std::ranges::none_of(text, [](char c) {
        const auto byte = static_cast<unsigned char>(c);
        return byte < 0x20 || byte == 0x7F;
    });
}

}  // namespace

std::string_view to_string(Access access) {
    switch (access) {
        case Access::read:
            return "read";
        case Access::read_write:
            return "read_write";
    }
    return "?";
}

std::string names(const Roles& roles) {
    std::string text;
    for (const auto& [name, role] : roles)
        text += fmt::format("{}{}", text.empty() ? "" : ", ", name);
    return text;
}

Expected<std::string, std::string> parse_role(std::span<const std::uint8_t> der) {
    const unsigned char* cursor = der.data();
    // OpenSSL's DER decoder: the tag must be UTF8String's, the length within the bytes.
    const openssl::String value(
        d2i_ASN1_UTF8STRING(nullptr, &cursor, static_cast<long>(der.size())));
    if (!value) return Unexpected(std::string("not a DER-encoded ASN.1 UTF8String"));
    if (cursor != der.data() + der.size())
        return Unexpected(
            fmt::format("{} bytes after the UTF8String", der.data() + der.size() - cursor));
    // Converting to UTF-8 checks that it is UTF-8.
    unsigned char* utf8 = nullptr;
    const int length = ASN1_STRING_to_UTF8(&utf8, value.get());
    const openssl::Buffer owned(utf8);
    if (length < 0) return Unexpected(std::string("the UTF8String is not valid UTF-8"));
    std::string role(reinterpret_cast<const char*>(utf8), static_cast<std::size_t>(length));
    if (role.empty()) return Unexpected(std::string("the role is empty"));
    if (role.size() > max_role_length)
        return Unexpected(
            fmt::format("the role is {} bytes long, more than {}", role.size(), max_role_length));
    if (!printable(role)) return Unexpected(std::string("the role has control characters"));
    return role;
}

Rights rights_of(const CertificateRole& certificate, std::string_view default_role,
                 const Roles& roles) {
    using Kind = CertificateRole::Kind;
    std::string name;
    std::string source;
    switch (certificate.kind) {
        case Kind::malformed:
            return {{},
                    std::nullopt,
                    fmt::format("malformed role extension ({}): no rights", certificate.text)};
        case Kind::valid:
            name = certificate.text;
            source = "from the certificate";
            break;
        case Kind::absent:
            if (default_role.empty())
                return {
                    {}, std::nullopt, "no role in the certificate and no default_role: no rights"};
            name = default_role;
            source = "default_role (no role in the certificate)";
            break;
    }
    const auto found = roles.find(name);
    if (found == roles.end())
        return {name, std::nullopt,
                fmt::format("role {} {} is not configured: no rights", name, source)};
    return {name, found->second,
            fmt::format("role {} {}, {}", name, source, to_string(found->second.access))};
}

bool is_write(std::uint8_t function) {
    switch (function) {
        case 0x05:  // write single coil
        case 0x06:  // write single register
        case 0x0F:  // write multiple coils
        case 0x10:  // write multiple registers
        case 0x16:  // mask write register
        case 0x17:  // read/write multiple registers
            return true;
        default:
            return false;
    }
}

bool permits(const Rights& rights, int unit_id, std::uint8_t function) {
    if (!rights.grants || unit_id < 0 || unit_id > 255) return false;
    if (!rights.grants->units.test(static_cast<std::size_t>(unit_id))) return false;
    return rights.grants->access == Access::read_write || !is_write(function);
}

}  // namespace ioport::modbus_security
