// A TLS server's context as every listener of the daemon makes it (Modbus/TCP Security,
// gateway.md §5.6; the HTTP side, §7.1): one cipher policy, one way of loading a certificate and
// of asking for and checking clients' certificates. What a listener does with a verified client
// (a Modbus role, an HTTP user) is its own.
#pragma once

#include <memory>
#include <string>
#include <string_view>

#include <boost/asio/ssl.hpp>

#include "config/gateway_config.hpp"
#include "link/asio.hpp"
#include "protocol/error.hpp"

namespace ioport::daemon {

using TlsContext = std::shared_ptr<asio::ssl::context>;

// TLS 1.2 and 1.3 only; for TLS 1.2 ECDHE with AES-GCM or ChaCha20-Poly1305 (no RSA key exchange,
// no CBC, no SHA-1); TLS 1.3's own suites.
inline constexpr const char* tls12_ciphers =
    "ECDHE-ECDSA-AES128-GCM-SHA256:ECDHE-RSA-AES128-GCM-SHA256:"
    "ECDHE-ECDSA-AES256-GCM-SHA384:ECDHE-RSA-AES256-GCM-SHA384:"
    "ECDHE-ECDSA-CHACHA20-POLY1305:ECDHE-RSA-CHACHA20-POLY1305";
inline constexpr const char* tls13_ciphersuites =
    "TLS_AES_128_GCM_SHA256:TLS_AES_256_GCM_SHA384:TLS_CHACHA20_POLY1305_SHA256";

struct TlsServerSettings {
    std::string_view section;      // "modbus.tls", for messages
    std::string_view certificate;  // its path, for messages
    std::string_view certificate_pem;
    std::string_view key_pem;
    std::string_view client_ca_pem;   // "" = none
    std::string_view client_crl_pem;  // "" = none
    config::ClientAuth client_auth = config::ClientAuth::none;
    config::TlsVersion min_version = config::TlsVersion::tls12;
    config::TlsVersion max_version = config::TlsVersion::tls13;
    // Sessions are found again by it: OpenSSL refuses to resume a session of a context that
    // verifies clients and has none.
    std::string_view session_id_context;
};

// The server's context: the certificate chain and key, clients' certificates asked for, required
// and verified as `client_auth` says (against client_ca and client_crl), session resumption from
// the server's cache. A context is kept by each connection made with it, so that a reload can
// replace it while they stay open.
Result<TlsContext> make_tls_server_context(const TlsServerSettings& settings);

// The subject of the client's certificate, RFC 2253 ("CN=hmi-1,O=Plant"), and its common name;
// "" when it sent none.
std::string peer_subject(SSL* connection);
std::string peer_common_name(SSL* connection);

// Why a handshake failed, for the log: OpenSSL's reason and, where the client's certificate was
// refused, the verification's: "certificate verify failed: certificate has expired".
std::string handshake_failure(const boost::system::error_code& error, SSL* connection);

}  // namespace ioport::daemon
