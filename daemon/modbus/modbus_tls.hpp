// The TLS side of Modbus/TCP Security (gateway.md §5.6): the server's context made from the
// settings, and what an established connection's client certificate says. The authorisation
// itself is pure (protocol/modbus_security); the connection logic is the Modbus server's, with
// TLS as its second transport.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "config/gateway_config.hpp"
#include "daemon/base/tls_server.hpp"
#include "link/asio.hpp"
#include "protocol/error.hpp"
#include "protocol/modbus_security.hpp"

namespace ioport::daemon {

using TlsStream = asio::ssl::stream<asio::ip::tcp::socket>;

// The server's context (tls_server.hpp): client certificates required and verified against
// client_ca (and client_crl, if any).
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

}  // namespace ioport::daemon
