// A TCP client that sends and receives Modbus frames byte for byte, for what libmodbus refuses
// to send (quantities over the limits, unknown function codes, broken headers, pipelining) or
// when a test must act while a request is in flight.
#pragma once

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <initializer_list>
#include <optional>
#include <string>
#include <vector>

#include "tests/support/timing.hpp"

namespace ioport::test {

using namespace std::chrono_literals;
using Bytes = std::vector<std::uint8_t>;

inline Bytes be16(std::initializer_list<std::uint16_t> words) {
    Bytes bytes;
    for (const auto word : words) {
        bytes.push_back(static_cast<std::uint8_t>(word >> 8));
        bytes.push_back(static_cast<std::uint8_t>(word & 0xFF));
    }
    return bytes;
}

// MBAP header (protocol id 0, the length of what follows) and the PDU.
// A PDU: the function code, then big-endian words, then raw bytes.
inline Bytes pdu(std::uint8_t function, std::initializer_list<std::uint16_t> words,
                 const Bytes& tail = {}) {
    Bytes bytes{function};
    const auto fields = be16(words);
    bytes.insert(bytes.end(), fields.begin(), fields.end());
    bytes.insert(bytes.end(), tail.begin(), tail.end());
    return bytes;
}

inline Bytes adu(std::uint16_t transaction, std::uint8_t unit, const Bytes& request) {
    auto bytes = be16({transaction, 0, static_cast<std::uint16_t>(request.size() + 1)});
    bytes.push_back(unit);
    bytes.insert(bytes.end(), request.begin(), request.end());
    return bytes;
}

struct Response {
    std::uint16_t transaction = 0;
    std::uint8_t unit = 0;
    Bytes pdu;
    // The exception code, or 0 for a normal response.
    int exception() const { return !pdu.empty() && (pdu[0] & 0x80) ? pdu.at(1) : 0; }
    std::uint16_t word(std::size_t i) const {  // register i of a read response
        return static_cast<std::uint16_t>(pdu.at(2 + 2 * i) << 8 | pdu.at(3 + 2 * i));
    }
};

class RawClient {
  public:
    // `receive_buffer`: SO_RCVBUF in bytes before connecting (0: the system's), so that a client
    // that does not read fills its window quickly.
    explicit RawClient(std::uint16_t port, const std::string& host = "127.0.0.1",
                       int receive_buffer = 0) {
        const bool v6 = host.find(':') != std::string::npos;
        fd_ = ::socket(v6 ? AF_INET6 : AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (fd_ < 0) return;
        if (receive_buffer > 0)
            ::setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &receive_buffer, sizeof receive_buffer);
        sockaddr_storage storage{};
        socklen_t length = 0;
        if (v6) {
            auto* address = reinterpret_cast<sockaddr_in6*>(&storage);
            address->sin6_family = AF_INET6;
            address->sin6_port = htons(port);
            ::inet_pton(AF_INET6, host.c_str(), &address->sin6_addr);
            length = sizeof(sockaddr_in6);
        } else {
            auto* address = reinterpret_cast<sockaddr_in*>(&storage);
            address->sin_family = AF_INET;
            address->sin_port = htons(port);
            ::inet_pton(AF_INET, host.c_str(), &address->sin_addr);
            length = sizeof(sockaddr_in);
        }
        connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&storage), length) == 0;
    }
    ~RawClient() {
        if (fd_ >= 0) ::close(fd_);
    }
    RawClient(const RawClient&) = delete;
    RawClient& operator=(const RawClient&) = delete;

    bool connected() const { return connected_; }
    bool send(const Bytes& bytes) {
        return ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL) ==
               static_cast<ssize_t>(bytes.size());
    }
    void shutdown_write() { ::shutdown(fd_, SHUT_WR); }

    // The next whole response; nullopt when the connection closed or nothing came in time. The
    // default deadline catches a hang, stretched like every upper bound (timing.hpp): a new
    // connection may queue behind a crowd the daemon is still accepting.
    std::optional<Response> receive(std::chrono::milliseconds deadline = 3s * slowdown) {
        const auto until = std::chrono::steady_clock::now() + deadline;
        for (;;) {
            if (buffer_.size() >= 7) {
                const std::size_t total =
                    6 + static_cast<std::size_t>(buffer_[4] << 8 | buffer_[5]);
                if (buffer_.size() >= total) {
                    Response response{static_cast<std::uint16_t>(buffer_[0] << 8 | buffer_[1]),
                                      buffer_[6],
                                      {buffer_.begin() + 7, buffer_.begin() + total}};
                    buffer_.erase(buffer_.begin(), buffer_.begin() + total);
                    return response;
                }
            }
            if (!fill(until)) return std::nullopt;
        }
    }
    std::optional<Response> ask(std::uint8_t unit, const Bytes& request,
                                std::uint16_t transaction = 0x4D42) {
        if (!send(adu(transaction, unit, request))) return std::nullopt;
        return receive();
    }
    // True when the server closed the connection within `deadline` without sending anything.
    bool closed_silently(std::chrono::milliseconds deadline) {
        const auto until = std::chrono::steady_clock::now() + deadline;
        while (fill(until)) {
        }
        return closed_ && buffer_.empty();
    }
    // Has the server closed the connection? Does not wait.
    bool closed_now() {
        fill(std::chrono::steady_clock::now());
        return closed_;
    }

  private:
    // Reads what is there (waiting until `until` for the first bytes); false on EOF or timeout.
    bool fill(std::chrono::steady_clock::time_point until) {
        if (closed_ || fd_ < 0) return false;
        pollfd fd{fd_, POLLIN, 0};
        const auto left =
            std::max<long long>(0, std::chrono::duration_cast<std::chrono::milliseconds>(
                                       until - std::chrono::steady_clock::now())
                                       .count());
        if (::poll(&fd, 1, static_cast<int>(left)) <= 0) return false;
        std::array<std::uint8_t, 4096> chunk{};
        const auto n = ::recv(fd_, chunk.data(), chunk.size(), 0);
        if (n <= 0) {  // EOF, or reset by a server that closed with our request unread
            closed_ = true;
            return false;
        }
        buffer_.insert(buffer_.end(), chunk.begin(), chunk.begin() + n);
        return true;
    }

    int fd_ = -1;
    bool connected_ = false;
    bool closed_ = false;
    Bytes buffer_;
};

}  // namespace ioport::test
