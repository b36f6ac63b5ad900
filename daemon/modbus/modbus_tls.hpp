// The TLS side of Modbus/TCP Security (gateway.md §5.6): the server's context made from the
// settings, and what an established connection's client certificate says. The authorisation
// itself is pure (protocol/modbus_security); the connection logic is the Modbus server's, with
// TLS as its second transport.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include <boost/asio/ssl.hpp>

#include "config/gateway_config.hpp"
#include "link/asio.hpp"
#include "protocol/error.hpp"
#include "protocol/modbus_security.hpp"

namespace ioport::daemon {

using TlsStream = asio::ssl::stream<asio::ip::tcp::socket>;
using TlsContext = std::shared_ptr<asio::ssl::context>;

// TLS 1.2 and 1.3 only; for TLS 1.2 ECDHE with AES-GCM or ChaCha20-Poly1305 (no RSA key exchange,
// no CBC, no SHA-1); TLS 1.3's own suites.
inline constexpr const char* tls12_ciphers =
    "ECDHE-ECDSA-AES128-GCM-SHA256:ECDHE-RSA-AES128-GCM-SHA256:"
    "ECDHE-ECDSA-AES256-GCM-SHA384:ECDHE-RSA-AES256-GCM-SHA384:"
    "ECDHE-ECDSA-CHACHA20-POLY1305:ECDHE-RSA-CHACHA20-POLY1305";
inline constexpr const char* tls13_ciphersuites =
    "TLS_AES_128_GCM_SHA256:TLS_AES_256_GCM_SHA384:TLS_CHACHA20_POLY1305_SHA256";

// The server's context: the certificate chain and key, client certificates required and verified
// against client_ca (and client_crl, if any), session resumption (session ids and tickets). A
// context is kept by each connection made with it, so that a reload can replace it while they stay
// open.
Result<TlsContext> make_tls_context(const config::TlsSettings& settings);

// A server-side stream over an accepted socket, as the listener makes each: OpenSSL keeps its
// record buffers between records (Asio asks it to free them after each, a tenth of a TLS
// request's instructions in benchmark 8a, to save 34 KiB a connection).
std::unique_ptr<TlsStream> make_tls_stream(asio::ip::tcp::socket socket,
                                           asio::ssl::context& context);

// The client of an established connection, as its certificate says.
struct TlsPeer {
    std::string subject;  // RFC 2253: "CN=hmi-1,O=Plant"
    modbus_security::CertificateRole role;
};
TlsPeer tls_peer(TlsStream& stream);

// When a CRL of `context` (modbus.tls.client_crl) revokes the client's certificate: its serial,
// in hex. OpenSSL verifies the chain at a full handshake only, not on a resumed session, and a
// connection keeps the context it was accepted with: a certificate revoked by a reload is found
// here.
std::optional<std::string> revoked_serial(asio::ssl::context& context, TlsStream& stream);

// Why a handshake failed, for the log: OpenSSL's reason and, where the client's certificate was
// refused, the verification's: "certificate verify failed: certificate has expired".
std::string handshake_failure(const boost::system::error_code& error, TlsStream& stream);

}  // namespace ioport::daemon
