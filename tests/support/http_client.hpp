// A small synchronous HTTP/1.1 client over a plain TCP socket, for tests of ioportd's HTTP side:
// every wait is bounded by a deadline, and the bytes sent are exactly those the test asks for, so
// that it can send what a well-behaved client would not (oversized headers, a request trickled
// byte by byte, other methods).
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace ioport::test {

using namespace std::chrono_literals;

struct HttpReply {
    int status = 0;  // 0: no response (see `error`)
    std::vector<std::pair<std::string, std::string>> headers;
    std::string body;
    std::string error;  // why there is no (whole) response: "refused", "closed", "timeout", ...

    // The first header of that name (case-insensitive), or nullopt.
    std::optional<std::string> header(std::string_view name) const;
};

// One TCP connection to an HTTP server; closed on destruction.
class HttpConnection {
  public:
    // `source`: the address it connects from ("": the kernel's choice), such as 127.0.0.9 for
    // another client of the loopback.
    explicit HttpConnection(std::uint16_t port, const std::string& host = "127.0.0.1",
                            const std::string& source = "");
    ~HttpConnection();
    HttpConnection(const HttpConnection&) = delete;
    HttpConnection& operator=(const HttpConnection&) = delete;

    bool connected() const { return fd_ >= 0; }
    // Sends bytes as they are; false if the connection is gone.
    bool send(std::string_view bytes);
    // Reads one response within `deadline`; `head`: a response to HEAD, which has no body
    // whatever its Content-Length says.
    HttpReply receive(std::chrono::milliseconds deadline = 5s, bool head = false);
    // A GET (or another method) on this connection, kept alive.
    HttpReply request(std::string_view method, std::string_view target,
                      std::chrono::milliseconds deadline = 5s, std::string_view extra_headers = "");
    // True when the server closed the connection (EOF or reset) within `deadline`; whatever it
    // sent before is kept in received().
    bool wait_closed(std::chrono::milliseconds deadline);
    const std::string& received() const { return buffer_; }

  private:
    // Reads what is there, waiting until `until` for it; false on EOF, reset or timeout.
    bool fill(std::chrono::steady_clock::time_point until);

    int fd_ = -1;
    bool closed_ = false;
    std::string buffer_;
};

// A request on a fresh connection (Connection: close).
HttpReply http_request(std::uint16_t port, std::string_view method, std::string_view target,
                       std::chrono::milliseconds deadline = 5s,
                       std::string_view extra_headers = "");
inline HttpReply http_get(std::uint16_t port, std::string_view target,
                          std::chrono::milliseconds deadline = 5s) {
    return http_request(port, "GET", target, deadline);
}

}  // namespace ioport::test
