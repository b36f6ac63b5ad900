#include "sim/control_client.hpp"

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>

#include <fmt/format.h>

namespace ioport::sim {

ControlClient::~ControlClient() {
    if (fd_ >= 0) ::close(fd_);
}

Result<> ControlClient::connect(const std::string& socket_path, std::chrono::milliseconds timeout) {
    sockaddr_un address{};
    if (socket_path.size() >= sizeof(address.sun_path))
        return fail(Errc::invalid_argument, fmt::format("socket path too long: {}", socket_path));
    fd_ = ::socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd_ < 0) return fail(Errc::io_error, std::strerror(errno));
    // Every read and write on the control socket is bounded by `timeout`.
    timeval tv{static_cast<time_t>(timeout.count() / 1000),
               static_cast<suseconds_t>(timeout.count() % 1000 * 1000)};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    ::setsockopt(fd_, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    address.sun_family = AF_UNIX;
    std::memcpy(address.sun_path, socket_path.c_str(), socket_path.size());
    if (::connect(fd_, reinterpret_cast<const sockaddr*>(&address), sizeof address) != 0)
        return fail(
            errno == ENOENT ? Errc::port_not_found : Errc::io_error,
            fmt::format("cannot reach the simulator at {}: {}", socket_path, std::strerror(errno)));
    return {};
}

Result<std::string> ControlClient::command(std::string_view line) {
    if (fd_ < 0) return fail(Errc::port_closed, "not connected to a simulator");
    const std::string request = std::string(line) + "\n";
    if (::send(fd_, request.data(), request.size(), MSG_NOSIGNAL) !=
        static_cast<ssize_t>(request.size()))
        return fail(Errc::io_error,
                    fmt::format("sending to the simulator: {}", std::strerror(errno)));
    std::string data;
    for (;;) {
        const auto newline = pending_.find('\n');
        if (newline == std::string::npos) {
            std::array<char, 4096> buffer{};
            const auto n = ::recv(fd_, buffer.data(), buffer.size(), 0);
            if (n <= 0)
                return fail(n == 0 ? Errc::port_lost : Errc::timeout,
                            fmt::format("the simulator did not answer '{}'", line));
            pending_.append(buffer.data(), static_cast<std::size_t>(n));
            continue;
        }
        std::string reply_line = pending_.substr(0, newline);
        pending_.erase(0, newline + 1);
        if (reply_line == "ok" || reply_line.starts_with("ok ")) {
            if (reply_line.size() > 3) data += reply_line.substr(3);
            return data;
        }
        if (reply_line.starts_with("error"))
            return fail(Errc::invalid_argument,
                        reply_line.size() > 6 ? reply_line.substr(6) : std::string("error"));
        data += reply_line + "\n";
    }
}

}  // namespace ioport::sim
