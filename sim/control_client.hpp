// A blocking client of the simulator's control socket, for tests and `ioport-sim ctl`.
#pragma once

#include <chrono>
#include <string>
#include <string_view>

#include "protocol/error.hpp"

namespace ioport::sim {

class ControlClient {
  public:
    ControlClient() = default;
    ControlClient(const ControlClient&) = delete;
    ControlClient& operator=(const ControlClient&) = delete;
    ~ControlClient();

    Result<> connect(const std::string& socket_path,
                     std::chrono::milliseconds timeout = std::chrono::seconds(5));
    // Sends one command; returns the data lines of an "ok" reply (and the text after "ok"), or
    // the "error" line's text as an error.
    Result<std::string> command(std::string_view line);

  private:
    int fd_ = -1;
    std::string pending_;
};

}  // namespace ioport::sim
