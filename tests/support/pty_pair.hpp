// A scripted device on a pty in the test's own io_context: the SerialLink under test opens the
// slave side, the test decides byte for byte what comes back and when.
#pragma once

#include <chrono>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "link/asio.hpp"

namespace ioport::test {

using namespace std::chrono_literals;

struct Reply {
    std::chrono::milliseconds after;
    std::string bytes;
};
// Called with each request frame (terminator stripped); returns what to send and when.
using Script = std::function<std::vector<Reply>(const std::string& request)>;

class PtyDevice {
  public:
    PtyDevice(asio::io_context& io, char terminator = '\r');
    ~PtyDevice();
    const std::string& path() const { return path_; }
    // Starts answering requests as `script` says.
    void serve(Script script);
    // Writes bytes at once, unasked.
    void send(std::string_view bytes);
    // Closes both ends, as when a USB adapter is pulled out.
    void hang_up();
    const std::vector<std::string>& requests() const { return requests_; }

  private:
    asio::awaitable<void> read_requests();

    asio::io_context& io_;
    char terminator_;
    asio::posix::stream_descriptor master_;
    int slave_fd_ = -1;
    std::string path_;
    Script script_;
    std::vector<std::string> requests_;
};

// Runs `test` on `io` until it finishes; fails the test if that takes longer than `deadline`.
void run_until_done(asio::io_context& io, const std::function<asio::awaitable<void>()>& test,
                    std::chrono::milliseconds deadline = 10s);

// Runs `io` until `condition` holds; false if not within `deadline`.
bool run_until(asio::io_context& io, const std::function<bool()>& condition,
               std::chrono::milliseconds deadline = 5s);

}  // namespace ioport::test
