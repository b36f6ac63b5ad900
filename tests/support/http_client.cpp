#include "tests/support/http_client.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cstring>

#include <fmt/format.h>

namespace ioport::test {
namespace {

using Clock = std::chrono::steady_clock;

bool iequal(std::string_view a, std::string_view b) {
    return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
               return std::tolower(static_cast<unsigned char>(x)) ==
                      std::tolower(static_cast<unsigned char>(y));
           });
}

std::string_view trimmed(std::string_view text) {
    while (!text.empty() && (text.front() == ' ' || text.front() == '\t'))
        text.remove_prefix(1);
    while (!text.empty() && (text.back() == ' ' || text.back() == '\t' || text.back() == '\r'))
        text.remove_suffix(1);
    return text;
}

// The status line and headers of `head` (without the blank line); false if malformed.
bool parse_head(std::string_view head, HttpReply& reply) {
    const auto line_end = head.find("\r\n");
    const auto status_line = head.substr(0, line_end);
    // "HTTP/1.1 200 OK"
    if (!status_line.starts_with("HTTP/1.") || status_line.size() < 12) return false;
    const auto code = status_line.substr(9, 3);
    if (!std::all_of(code.begin(), code.end(), [](char c) { return c >= '0' && c <= '9'; }))
        return false;
    reply.status = std::stoi(std::string(code));
    auto rest = line_end == std::string_view::npos ? std::string_view() : head.substr(line_end + 2);
    while (!rest.empty()) {
        const auto end = rest.find("\r\n");
        const auto line = rest.substr(0, end);
        rest = end == std::string_view::npos ? std::string_view() : rest.substr(end + 2);
        const auto colon = line.find(':');
        if (colon == std::string_view::npos) return false;
        reply.headers.emplace_back(std::string(line.substr(0, colon)),
                                   std::string(trimmed(line.substr(colon + 1))));
    }
    return true;
}

}  // namespace

std::optional<std::string> HttpReply::header(std::string_view name) const {
    for (const auto& [key, value] : headers)
        if (iequal(key, name)) return value;
    return std::nullopt;
}

HttpConnection::HttpConnection(std::uint16_t port, const std::string& host,
                               const std::string& source) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return;
    if (!source.empty()) {
        sockaddr_in from{};
        from.sin_family = AF_INET;
        ::inet_pton(AF_INET, source.c_str(), &from.sin_addr);
        if (::bind(fd, reinterpret_cast<sockaddr*>(&from), sizeof from) != 0) {
            ::close(fd);
            return;
        }
    }
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(port);
    ::inet_pton(AF_INET, host.c_str(), &address.sin_addr);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) {
        ::close(fd);
        return;
    }
    fd_ = fd;
}

HttpConnection::~HttpConnection() {
    if (fd_ >= 0) ::close(fd_);
}

bool HttpConnection::send(std::string_view bytes) {
    if (fd_ < 0) return false;
    while (!bytes.empty()) {
        const auto n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
        if (n <= 0) return false;
        bytes.remove_prefix(static_cast<std::size_t>(n));
    }
    return true;
}

bool HttpConnection::fill(Clock::time_point until) {
    if (closed_ || fd_ < 0) return false;
    pollfd fd{fd_, POLLIN, 0};
    const auto left = std::max<long long>(
        0, std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now()).count());
    if (::poll(&fd, 1, static_cast<int>(left)) <= 0) return false;
    std::array<char, 16384> chunk{};
    const auto n = ::recv(fd_, chunk.data(), chunk.size(), 0);
    if (n <= 0) {  // EOF, or reset by a server that closed with our bytes unread
        closed_ = true;
        return false;
    }
    buffer_.append(chunk.data(), static_cast<std::size_t>(n));
    return true;
}

HttpReply HttpConnection::receive(std::chrono::milliseconds deadline, bool head) {
    HttpReply reply;
    if (fd_ < 0) {
        reply.error = "refused";
        return reply;
    }
    const auto until = Clock::now() + deadline;
    std::size_t head_end = std::string::npos;
    while ((head_end = buffer_.find("\r\n\r\n")) == std::string::npos) {
        if (!fill(until)) {
            reply.error =
                closed_ ? (buffer_.empty() ? "closed" : "closed in the headers") : "timeout";
            return reply;
        }
    }
    if (!parse_head(std::string_view(buffer_).substr(0, head_end), reply)) {
        reply.error = "malformed response head: " + buffer_.substr(0, head_end);
        reply.status = 0;
        return reply;
    }
    buffer_.erase(0, head_end + 4);
    const bool no_body = head || reply.status == 204 || reply.status == 304 || reply.status < 200;
    if (no_body) return reply;
    if (const auto length = reply.header("Content-Length")) {
        const auto size = static_cast<std::size_t>(std::stoull(*length));
        while (buffer_.size() < size) {
            if (!fill(until)) {
                reply.error = closed_ ? "closed in the body" : "timeout in the body";
                return reply;
            }
        }
        reply.body = buffer_.substr(0, size);
        buffer_.erase(0, size);
        return reply;
    }
    // No length (ioportd always sends one): the body ends with the connection.
    while (fill(until)) {
    }
    if (!closed_) reply.error = "timeout in a body without Content-Length";
    reply.body = std::exchange(buffer_, {});
    return reply;
}

HttpReply HttpConnection::request(std::string_view method, std::string_view target,
                                  std::chrono::milliseconds deadline,
                                  std::string_view extra_headers) {
    const auto text =
        fmt::format("{} {} HTTP/1.1\r\nHost: 127.0.0.1\r\nUser-Agent: ioportd-test\r\n{}\r\n",
                    method, target, extra_headers);
    if (!send(text)) {
        HttpReply reply;
        reply.error = fd_ < 0 ? "refused" : fmt::format("send: {}", std::strerror(errno));
        return reply;
    }
    return receive(deadline, method == "HEAD");
}

bool HttpConnection::wait_closed(std::chrono::milliseconds deadline) {
    const auto until = Clock::now() + deadline;
    while (fill(until)) {
    }
    return closed_ || fd_ < 0;
}

HttpReply http_request(std::uint16_t port, std::string_view method, std::string_view target,
                       std::chrono::milliseconds deadline, std::string_view extra_headers) {
    HttpConnection connection(port);
    return connection.request(method, target, deadline,
                              fmt::format("Connection: close\r\n{}", extra_headers));
}

}  // namespace ioport::test
