#include "daemon/base/tls_server.hpp"

#include <fmt/format.h>
#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>

#include "protocol/openssl.hpp"

namespace ioport::daemon {
namespace {

// A client that reconnects within this time resumes its session instead of a full handshake.
// A plant has tens of clients, not hundreds; a session with its client certificate is a few KiB.
constexpr long session_lifetime_seconds = 3600;
constexpr long session_cache_size = 256;

Unexpected<Error> failed(const TlsServerSettings& settings, std::string_view what) {
    const unsigned long code = ERR_get_error();
    ERR_clear_error();
    const char* reason = code != 0 ? ERR_reason_error_string(code) : nullptr;
    return fail(Errc::invalid_argument,
                fmt::format("{}: {} ({}): {}", settings.section, what, settings.certificate,
                            reason != nullptr ? reason : "unknown OpenSSL error"));
}

// The CA's certificates, also named to clients in the certificate request so that a client
// with several certificates picks the right one.
Result<> trust_client_ca(SSL_CTX* context, const TlsServerSettings& settings) {
    const auto bio = openssl::memory(settings.client_ca_pem);
    X509_STORE* store = SSL_CTX_get_cert_store(context);
    int count = 0;
    while (const openssl::Certificate ca{PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr)}) {
        if (X509_STORE_add_cert(store, ca.get()) != 1 ||
            SSL_CTX_add_client_CA(context, ca.get()) != 1)
            return failed(settings, "adding the client CA");
        ++count;
    }
    ERR_clear_error();  // the end of the PEM text
    if (count == 0) return failed(settings, "the client CA file has no certificate");
    return {};
}

// Every client certificate checked against its CA's CRL (the leaf only: the client CA's own
// certificates are the operator's).
Result<> trust_client_crl(SSL_CTX* context, const TlsServerSettings& settings) {
    const auto bio = openssl::memory(settings.client_crl_pem);
    X509_STORE* store = SSL_CTX_get_cert_store(context);
    while (const openssl::Crl crl{PEM_read_bio_X509_CRL(bio.get(), nullptr, nullptr, nullptr)})
        if (X509_STORE_add_crl(store, crl.get()) != 1)
            return failed(settings, "adding the client CRL");
    ERR_clear_error();  // the end of the PEM text
    X509_STORE_set_flags(store, X509_V_FLAG_CRL_CHECK);
    return {};
}

// RequestClientCert and RequireAnyClientCert, in Go's words: a certificate is taken as the client
// sends it, unchecked (it then names no one: peer_common_name() is asked only of checked ones).
int accept_any(int /*preverified*/, X509_STORE_CTX* /*context*/) {
    return 1;
}

void set_verify(SSL_CTX* context, config::ClientAuth client_auth) {
    using config::ClientAuth;
    switch (client_auth) {
        case ClientAuth::none:
            SSL_CTX_set_verify(context, SSL_VERIFY_NONE, nullptr);
            return;
        case ClientAuth::request:
            SSL_CTX_set_verify(context, SSL_VERIFY_PEER, accept_any);
            return;
        case ClientAuth::require_any:
            SSL_CTX_set_verify(context, SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT,
                               accept_any);
            return;
        case ClientAuth::verify_if_given:
            SSL_CTX_set_verify(context, SSL_VERIFY_PEER, nullptr);
            return;
        case ClientAuth::require_and_verify:
            SSL_CTX_set_verify(context, SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT, nullptr);
            return;
    }
}

int version(config::TlsVersion version) {
    switch (version) {
        case config::TlsVersion::tls12:
            return TLS1_2_VERSION;
        case config::TlsVersion::tls13:
            return TLS1_3_VERSION;
    }
    return TLS1_2_VERSION;
}

}  // namespace

Result<TlsContext> make_tls_server_context(const TlsServerSettings& settings) {
    auto tls = std::make_shared<asio::ssl::context>(asio::ssl::context::tls_server);
    SSL_CTX* context = tls->native_handle();
    SSL_CTX_set_min_proto_version(context, version(settings.min_version));
    SSL_CTX_set_max_proto_version(context, version(settings.max_version));
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
    if (!settings.client_ca_pem.empty())
        if (auto trusted = trust_client_ca(context, settings); !trusted)
            return Unexpected(trusted.error());
    if (!settings.client_crl_pem.empty())
        if (auto checked = trust_client_crl(context, settings); !checked)
            return Unexpected(checked.error());
    set_verify(context, settings.client_auth);
    SSL_CTX_set_session_id_context(
        context, reinterpret_cast<const unsigned char*>(settings.session_id_context.data()),
        static_cast<unsigned>(settings.session_id_context.size()));
    SSL_CTX_set_session_cache_mode(context, SSL_SESS_CACHE_SERVER);
    SSL_CTX_sess_set_cache_size(context, session_cache_size);
    SSL_CTX_set_timeout(context, session_lifetime_seconds);
    SSL_CTX_set_num_tickets(context, 1);  // TLS 1.3: one per handshake is enough to resume
    return tls;
}

std::string peer_subject(SSL* connection) {
    const openssl::Certificate certificate(SSL_get1_peer_certificate(connection));
    if (!certificate) return {};
    const openssl::Bio text(BIO_new(BIO_s_mem()));
    X509_NAME_print_ex(text.get(), X509_get_subject_name(certificate.get()), 0, XN_FLAG_RFC2253);
    char* data = nullptr;
    const long length = BIO_get_mem_data(text.get(), &data);
    if (data == nullptr || length <= 0) return {};
    return {data, static_cast<std::size_t>(length)};
}

std::string peer_common_name(SSL* connection) {
    const openssl::Certificate certificate(SSL_get1_peer_certificate(connection));
    if (!certificate) return {};
    const X509_NAME* subject = X509_get_subject_name(certificate.get());
    // One CN: a certificate with two names no one unambiguously.
    const int at = X509_NAME_get_index_by_NID(subject, NID_commonName, -1);
    if (at < 0 || X509_NAME_get_index_by_NID(subject, NID_commonName, at) >= 0) return {};
    const ASN1_STRING* value = X509_NAME_ENTRY_get_data(X509_NAME_get_entry(subject, at));
    unsigned char* utf8 = nullptr;
    const int length = ASN1_STRING_to_UTF8(&utf8, value);
    if (length < 0) return {};
    const openssl::Buffer owned(utf8);
    return {reinterpret_cast<const char*>(utf8), static_cast<std::size_t>(length)};
}

std::string handshake_failure(const boost::system::error_code& error, SSL* connection) {
    const long verified = SSL_get_verify_result(connection);
    if (verified != X509_V_OK)
        return fmt::format("{}: {}", error.message(), X509_verify_cert_error_string(verified));
    return error.message();
}

}  // namespace ioport::daemon
