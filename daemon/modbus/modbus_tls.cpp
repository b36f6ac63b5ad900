#include "daemon/modbus/modbus_tls.hpp"

#include <memory>

#include <fmt/format.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>

#include "protocol/openssl.hpp"

namespace ioport::daemon {

Result<TlsContext> make_tls_context(const config::TlsSettings& settings) {
    return make_tls_server_context({.section = "modbus.tls",
                                    .certificate = settings.certificate,
                                    .certificate_pem = settings.certificate_pem,
                                    .key_pem = settings.key_pem,
                                    .client_ca_pem = settings.client_ca_pem,
                                    .client_crl_pem = settings.client_crl_pem,
                                    .client_auth = config::ClientAuth::require_and_verify,
                                    .session_id_context = "ioportd-modbus-tls"});
}

std::unique_ptr<TlsStream> make_tls_stream(asio::ip::tcp::socket socket,
                                           asio::ssl::context& context) {
    auto stream = std::make_unique<TlsStream>(std::move(socket), context);
    SSL_clear_mode(stream->native_handle(), SSL_MODE_RELEASE_BUFFERS);
    return stream;
}

TlsPeer tls_peer(TlsStream& stream) {
    TlsPeer peer{.subject = peer_subject(stream.native_handle()), .role = {}};
    const openssl::Certificate certificate(SSL_get1_peer_certificate(stream.native_handle()));
    if (!certificate) return peer;  // not after a verified handshake: verification requires one

    const openssl::Object oid(OBJ_txt2obj(std::string(modbus_security::role_oid).c_str(), 1));
    using Kind = modbus_security::CertificateRole::Kind;
    const int at = X509_get_ext_by_OBJ(certificate.get(), oid.get(), -1);
    if (at < 0) return peer;  // absent
    if (X509_get_ext_by_OBJ(certificate.get(), oid.get(), at) >= 0) {
        peer.role = {Kind::malformed, "the certificate has two role extensions"};
        return peer;
    }
    const ASN1_OCTET_STRING* value = X509_EXTENSION_get_data(X509_get_ext(certificate.get(), at));
    const auto parsed = modbus_security::parse_role(
        {ASN1_STRING_get0_data(value), static_cast<std::size_t>(ASN1_STRING_length(value))});
    peer.role = parsed ? modbus_security::CertificateRole{Kind::valid, *parsed}
                       : modbus_security::CertificateRole{Kind::malformed, parsed.error()};
    return peer;
}

std::optional<std::string> revoked_serial(asio::ssl::context& context, TlsStream& stream) {
    const openssl::Certificate certificate(SSL_get1_peer_certificate(stream.native_handle()));
    if (!certificate) return std::nullopt;
    const X509_NAME* issuer = X509_get_issuer_name(certificate.get());
    // A handful of CRLs, read by one thread: the store needs no lock here.
    STACK_OF(X509_OBJECT)* objects =
        X509_STORE_get0_objects(SSL_CTX_get_cert_store(context.native_handle()));
    for (int i = 0; i < sk_X509_OBJECT_num(objects); ++i) {
        X509_CRL* crl = X509_OBJECT_get0_X509_CRL(sk_X509_OBJECT_value(objects, i));
        X509_REVOKED* entry = nullptr;
        // A CRL lists serials of its issuer's certificates only; the issuer is compared here.
        if (crl == nullptr || X509_NAME_cmp(X509_CRL_get_issuer(crl), issuer) != 0 ||
            X509_CRL_get0_by_cert(crl, &entry, certificate.get()) != 1)
            continue;
        const ASN1_INTEGER* serial = X509_get0_serialNumber(certificate.get());
        std::string hex;
        const unsigned char* bytes = ASN1_STRING_get0_data(serial);
        for (int b = 0; b < ASN1_STRING_length(serial); ++b)
            hex += fmt::format("{:02X}", bytes[b]);
        return hex;
    }
    return std::nullopt;
}

}  // namespace ioport::daemon
