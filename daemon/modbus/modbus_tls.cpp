#include "daemon/modbus/modbus_tls.hpp"

#include <memory>

#include <fmt/format.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>

#include "protocol/openssl.hpp"

namespace ioport::daemon {
namespace {

// Sessions are found again by this id: OpenSSL refuses to resume a session of a context that
// verifies clients and has none.
constexpr unsigned char session_id_context[] = "ioportd-modbus-tls";
// A client that reconnects within this time resumes its session instead of a full handshake.
// A plant has tens of Modbus clients, not hundreds; a session with its client certificate is a
// few KiB.
constexpr long session_lifetime_seconds = 3600;
constexpr long session_cache_size = 256;

Unexpected<Error> failed(const config::TlsSettings& settings, std::string_view what) {
    const unsigned long code = ERR_get_error();
    ERR_clear_error();
    const char* reason = code != 0 ? ERR_reason_error_string(code) : nullptr;
    return fail(Errc::invalid_argument,
                fmt::format("modbus.tls: {} ({}): {}", what, settings.certificate,
                            reason != nullptr ? reason : "unknown OpenSSL error"));
}

// The CA's certificates, also named to clients in the certificate request so that a client
// with several certificates picks the right one.
Result<> trust_client_ca(SSL_CTX* context, const config::TlsSettings& settings) {
    const auto bio = openssl::memory(settings.client_ca_pem);
    X509_STORE* store = SSL_CTX_get_cert_store(context);
    int count = 0;
    while (const openssl::Certificate ca{PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)}) {
        if (X509_STORE_add_cert(store, ca.get()) != 1 ||
            SSL_CTX_add_client_CA(context, ca.get()) != 1)
            return failed(settings, "adding client_ca");
        ++count;
    }
    ERR_clear_error();  // the end of the PEM text
    if (count == 0) return failed(settings, "client_ca has no certificate");
    return {};
}

// Every client certificate checked against its CA's CRL (the leaf only: client_ca's own
// certificates are the operator's).
Result<> trust_client_crl(SSL_CTX* context, const config::TlsSettings& settings) {
    if (settings.client_crl_pem.empty()) return {};
    const auto bio = openssl::memory(settings.client_crl_pem);
    X509_STORE* store = SSL_CTX_get_cert_store(context);
    while (const openssl::Crl crl{PEM_read_bio_X509_CRL(bio.get(), nullptr, nullptr, nullptr)})
        if (X509_STORE_add_crl(store, crl.get()) != 1) return failed(settings, "adding client_crl");
    ERR_clear_error();  // the end of the PEM text
    X509_STORE_set_flags(store, X509_V_FLAG_CRL_CHECK);
    return {};
}

}  // namespace

Result<TlsContext> make_tls_context(const config::TlsSettings& settings) {
    auto tls = std::make_shared<asio::ssl::context>(asio::ssl::context::tls_server);
    SSL_CTX* context = tls->native_handle();
    SSL_CTX_set_min_proto_version(context, TLS1_2_VERSION);
    // Sessions stay in the server's cache, and a ticket only names one (SSL_OP_NO_TICKET): a
    // stateless ticket carries the whole session, client certificate included, which OpenSSL 3.0
    // encodes for every full handshake and decodes for every resumption (benchmark 8b: 1,435
    // against 1,154 µs of CPU a full handshake, 886 against 311 µs a resumed one).
    SSL_CTX_set_options(context, SSL_OP_NO_COMPRESSION | SSL_OP_NO_RENEGOTIATION |
                                     SSL_OP_CIPHER_SERVER_PREFERENCE | SSL_OP_NO_TICKET);
    if (SSL_CTX_set_cipher_list(context, tls12_ciphers) != 1 ||
        SSL_CTX_set_ciphersuites(context, tls13_ciphersuites) != 1)
        return failed(settings, "setting the ciphers");
    boost::system::error_code ec;
    tls->use_certificate_chain(asio::buffer(settings.certificate_pem), ec);
    if (ec) return failed(settings, "loading the certificate");
    tls->use_private_key(asio::buffer(settings.key_pem), asio::ssl::context::pem, ec);
    if (ec || SSL_CTX_check_private_key(context) != 1) return failed(settings, "loading the key");
    if (auto trusted = trust_client_ca(context, settings); !trusted)
        return Unexpected(trusted.error());
    if (auto checked = trust_client_crl(context, settings); !checked)
        return Unexpected(checked.error());
    SSL_CTX_set_verify(context, SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT, nullptr);
    SSL_CTX_set_session_id_context(context, session_id_context, sizeof session_id_context - 1);
    SSL_CTX_set_session_cache_mode(context, SSL_SESS_CACHE_SERVER);
    SSL_CTX_sess_set_cache_size(context, session_cache_size);
    SSL_CTX_set_timeout(context, session_lifetime_seconds);
    SSL_CTX_set_num_tickets(context, 1);  // TLS 1.3: one per handshake is enough to resume
    return tls;
}

std::unique_ptr<TlsStream> make_tls_stream(asio::ip::tcp::socket socket,
                                           asio::ssl::context& context) {
    auto stream = std::make_unique<TlsStream>(std::move(socket), context);
    SSL_clear_mode(stream->native_handle(), SSL_MODE_RELEASE_BUFFERS);
    return stream;
}

TlsPeer tls_peer(TlsStream& stream) {
    TlsPeer peer;
    const openssl::Certificate certificate(SSL_get1_peer_certificate(stream.native_handle()));
    if (!certificate) return peer;  // not after a verified handshake: verification requires one
    const openssl::Bio text(BIO_new(BIO_s_mem()));
    X509_NAME_print_ex(text.get(), X509_get_subject_name(certificate.get()), 0, XN_FLAG_RFC2253);
    char* data = nullptr;
    const long length = BIO_get_mem_data(text.get(), &data);
    if (data != nullptr && length > 0) peer.subject.assign(data, static_cast<std::size_t>(length));

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

std::string handshake_failure(const boost::system::error_code& error, TlsStream& stream) {
    const long verified = SSL_get_verify_result(stream.native_handle());
    if (verified != X509_V_OK)
        return fmt::format("{}: {}", error.message(), X509_verify_cert_error_string(verified));
    return error.message();
}

}  // namespace ioport::daemon
