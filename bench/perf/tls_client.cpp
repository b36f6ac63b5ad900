#include "bench/perf/tls_client.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdlib>

#include <fmt/format.h>
#include <openssl/crypto.h>
#include <openssl/err.h>
#include <openssl/x509v3.h>

namespace ioport::bench {
namespace {

std::string openssl_error(std::string_view what) {
    const unsigned long code = ERR_get_error();
    ERR_clear_error();
    const char* reason = code != 0 ? ERR_reason_error_string(code) : nullptr;
    return fmt::format("{}: {}", what, reason != nullptr ? reason : "unknown OpenSSL error");
}

constexpr std::size_t mbap_length = 7;

// Every block OpenSSL allocates carries its size and whether it counts, ahead of the bytes it
// asked for (16 bytes keep malloc's alignment).
struct Header {
    std::size_t size;
    std::size_t counted;
};
static_assert(sizeof(Header) == 16);
std::atomic<std::int64_t> live_bytes{0};
std::atomic<bool> allocations_installed{false};
thread_local bool counting = false;

void* counted_malloc(std::size_t size, const char*, int) {
    auto* header = static_cast<Header*>(std::malloc(sizeof(Header) + size));
    if (header == nullptr) return nullptr;
    *header = {size, counting ? 1U : 0U};
    if (counting) live_bytes += static_cast<std::int64_t>(size);
    return header + 1;
}

void counted_free(void* p, const char*, int) {
    if (p == nullptr) return;
    auto* header = static_cast<Header*>(p) - 1;
    if (header->counted != 0) live_bytes -= static_cast<std::int64_t>(header->size);
    std::free(header);
}

void* counted_realloc(void* p, std::size_t size, const char* file, int line) {
    if (p == nullptr) return counted_malloc(size, file, line);
    if (size == 0) {
        counted_free(p, file, line);
        return nullptr;
    }
    const Header old = *(static_cast<Header*>(p) - 1);
    auto* header =
        static_cast<Header*>(std::realloc(static_cast<Header*>(p) - 1, sizeof(Header) + size));
    if (header == nullptr) return nullptr;
    if (old.counted != 0) live_bytes -= static_cast<std::int64_t>(old.size);
    *header = {size, old.counted != 0 || counting ? 1U : 0U};
    if (header->counted != 0) live_bytes += static_cast<std::int64_t>(size);
    return header + 1;
}

}  // namespace

bool OpenSslAllocations::install() {
    if (CRYPTO_set_mem_functions(counted_malloc, counted_realloc, counted_free) == 1)
        allocations_installed = true;
    return allocations_installed;
}

bool OpenSslAllocations::installed() {
    return allocations_installed;
}

OpenSslAllocations::Counting::Counting() {
    counting = true;
}

OpenSslAllocations::Counting::~Counting() {
    counting = false;
}

std::int64_t OpenSslAllocations::live() {
    return live_bytes;
}

TlsClientContext::TlsClientContext(const TlsClientSettings& settings) {
    decltype(context_) context(SSL_CTX_new(TLS_client_method()));
    if (!context) {
        failure_ = openssl_error("SSL_CTX_new");
        return;
    }
    SSL_CTX* c = context.get();
    SSL_CTX_set_min_proto_version(c, settings.version != 0 ? settings.version : TLS1_2_VERSION);
    if (settings.version != 0) SSL_CTX_set_max_proto_version(c, settings.version);
    if (settings.no_tickets) SSL_CTX_set_options(c, SSL_OP_NO_TICKET);
    // Sessions are kept by the benchmark's threads themselves (TlsConnection::session).
    SSL_CTX_set_session_cache_mode(c, SSL_SESS_CACHE_OFF);
    if (SSL_CTX_load_verify_locations(c, settings.ca.c_str(), nullptr) != 1) {
        failure_ = openssl_error("loading the CA " + settings.ca);
        return;
    }
    SSL_CTX_set_verify(c, SSL_VERIFY_PEER, nullptr);
    // The server's certificate names 127.0.0.1 (subjectAltName), as docs/tls.md's does.
    X509_VERIFY_PARAM_set1_ip_asc(SSL_CTX_get0_param(c), "127.0.0.1");
    if (!settings.certificate.empty() &&
        (SSL_CTX_use_certificate_chain_file(c, settings.certificate.c_str()) != 1 ||
         SSL_CTX_use_PrivateKey_file(c, settings.key.c_str(), SSL_FILETYPE_PEM) != 1)) {
        failure_ = openssl_error("loading the client certificate " + settings.certificate);
        return;
    }
    context_ = std::move(context);
}

TlsConnection::TlsConnection(const TlsClientContext& context, std::uint16_t port,
                             const SSL_SESSION* resume, std::chrono::milliseconds timeout)
    : buffer_(260) {
    if (!context.ok()) return;
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd_ < 0) return;
    const int one = 1;
    ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    const timeval limit{static_cast<time_t>(timeout.count() / 1000),
                        static_cast<suseconds_t>(timeout.count() % 1000 * 1000)};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &limit, sizeof limit);
    ::setsockopt(fd_, SOL_SOCKET, SO_SNDTIMEO, &limit, sizeof limit);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(port);
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0) return;
    SSL* ssl = SSL_new(context.get());
    if (ssl == nullptr) return;
    if (SSL_set_fd(ssl, fd_) != 1 ||
        (resume != nullptr && SSL_set_session(ssl, const_cast<SSL_SESSION*>(resume)) != 1) ||
        SSL_connect(ssl) != 1) {
        ERR_clear_error();
        SSL_free(ssl);
        return;
    }
    ssl_ = ssl;
}

TlsConnection::~TlsConnection() {
    if (ssl_ != nullptr) {
        // close_notify, as a well-behaved client says goodbye; the server's is not awaited.
        (void)SSL_shutdown(ssl_);
        SSL_free(ssl_);
        ERR_clear_error();
    }
    if (fd_ >= 0) ::close(fd_);
}

bool TlsConnection::resumed() const {
    return ssl_ != nullptr && SSL_session_reused(ssl_) == 1;
}

const char* TlsConnection::version() const {
    return ssl_ != nullptr ? SSL_get_version(ssl_) : "";
}

TlsSession TlsConnection::session() const {
    if (ssl_ == nullptr) return nullptr;
    TlsSession session(SSL_get1_session(ssl_));
    if (session && SSL_SESSION_is_resumable(session.get()) != 1) session.reset();
    return session;
}

bool TlsConnection::read_exactly(std::size_t count) {
    std::size_t have = 0;
    while (have < count) {
        std::size_t n = 0;
        if (SSL_read_ex(ssl_, buffer_.data() + have, count - have, &n) != 1) {
            ERR_clear_error();
            return false;
        }
        have += n;
    }
    return true;
}

TlsConnection::Reply TlsConnection::request(int unit, std::span<const std::uint8_t> pdu) {
    Reply reply;
    if (ssl_ == nullptr || pdu.empty() || pdu.size() > 253) return reply;
    ++transaction_;
    std::array<std::uint8_t, mbap_length + 253> adu{};
    const auto length = static_cast<std::uint16_t>(pdu.size() + 1);
    adu[0] = static_cast<std::uint8_t>(transaction_ >> 8);
    adu[1] = static_cast<std::uint8_t>(transaction_);
    adu[4] = static_cast<std::uint8_t>(length >> 8);
    adu[5] = static_cast<std::uint8_t>(length);
    adu[6] = static_cast<std::uint8_t>(unit);
    std::copy(pdu.begin(), pdu.end(), adu.begin() + mbap_length);
    std::size_t written = 0;
    if (SSL_write_ex(ssl_, adu.data(), mbap_length + pdu.size(), &written) != 1) {
        ERR_clear_error();
        return reply;
    }
    // The header, then the rest it announces (over the header, which is read by then).
    if (!read_exactly(mbap_length)) return reply;
    const auto id = static_cast<std::uint16_t>(buffer_[0] << 8 | buffer_[1]);
    const auto rest = static_cast<std::size_t>(buffer_[4] << 8 | buffer_[5]);
    if (id != transaction_ || rest < 2 || rest > 254) return reply;
    if (!read_exactly(rest - 1)) return reply;
    reply.answered = true;
    reply.pdu = std::span(buffer_.data(), rest - 1);
    reply.exception = (reply.pdu[0] & 0x80) != 0;
    return reply;
}

}  // namespace ioport::bench
