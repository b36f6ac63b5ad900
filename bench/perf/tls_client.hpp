// Benchmark 8's Modbus/TCP Security client: OpenSSL on a blocking socket, the MBAP ADU unchanged
// inside TLS (gateway.md §5.6), a client certificate, and the server's certificate verified
// against the plant CA as a real client does. Its CPU is not what benchmark 8 measures.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <openssl/ssl.h>

#include "protocol/openssl.hpp"

namespace ioport::bench {

struct TlsClientSettings {
    std::string ca;  // PEM file: the CA that signed the server's certificate
    // PEM files: the client's certificate and key; none (empty) for a server that asks for
    // none (benchmark 6d's HTTPS without client certificates).
    std::string certificate;
    std::string key;
    // TLS1_2_VERSION or TLS1_3_VERSION: only that version; 0: what the server prefers (1.3).
    int version = 0;
    // TLS 1.2: session ids only, no tickets (RFC 5077), so that resumption finds the session in
    // the server's cache.
    bool no_tickets = false;
};

// An OpenSSL client context. Shared by the connections and threads that use it (OpenSSL's
// contexts are safe to share once set up).
class TlsClientContext {
  public:
    explicit TlsClientContext(const TlsClientSettings& settings);
    bool ok() const { return context_ != nullptr; }
    SSL_CTX* get() const { return context_.get(); }
    // Why not ok().
    const std::string& failure() const { return failure_; }

  private:
    std::unique_ptr<SSL_CTX, openssl::Deleter<SSL_CTX_free>> context_;
    std::string failure_;
};

using TlsSession = std::unique_ptr<SSL_SESSION, openssl::Deleter<SSL_SESSION_free>>;

// One connection: TCP connect and the TLS handshake in the constructor, then Modbus requests;
// close_notify and close in the destructor.
class TlsConnection {
  public:
    // `resume`: offer this session (a TLS 1.3 ticket or a TLS 1.2 session id).
    TlsConnection(const TlsClientContext& context, std::uint16_t port,
                  const SSL_SESSION* resume = nullptr,
                  std::chrono::milliseconds timeout = std::chrono::seconds(10));
    ~TlsConnection();
    TlsConnection(const TlsConnection&) = delete;
    TlsConnection& operator=(const TlsConnection&) = delete;

    bool connected() const { return ssl_ != nullptr; }
    // The handshake resumed the session offered (SSL_session_reused).
    bool resumed() const;
    const char* version() const;
    // The session to offer next time, if the server gave a resumable one. After a response:
    // TLS 1.3's ticket comes after the handshake, and is read with the first response.
    TlsSession session() const;

    struct Reply {
        bool answered = false;   // a response of this transaction
        bool exception = false;  // of which a Modbus exception response
        std::span<const std::uint8_t> pdu;
    };
    // One request to `unit` and its response; its PDU is valid until the next request.
    Reply request(int unit, std::span<const std::uint8_t> pdu);

  private:
    bool read_exactly(std::size_t count);

    int fd_ = -1;
    SSL* ssl_ = nullptr;
    std::uint16_t transaction_ = 0;
    std::vector<std::uint8_t> buffer_;
};

// What OpenSSL allocates on the threads that count (benchmark 8c: a server connection's need).
// Its allocation functions must be replaced before its first allocation: main() installs them
// first thing; false when that was too late, and nothing is counted.
class OpenSslAllocations {
  public:
    static bool install();
    static bool installed();
    // While it lives, what OpenSSL allocates on this thread counts, until it is freed (on any
    // thread).
    class Counting {
      public:
        Counting();
        ~Counting();
        Counting(const Counting&) = delete;
        Counting& operator=(const Counting&) = delete;
    };
    // The bytes counted and not yet freed.
    static std::int64_t live();
};

}  // namespace ioport::bench
