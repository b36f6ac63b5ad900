// The serial link for command-line use: each call runs a private io_context until it is done.
#pragma once

#include "link/serial_link.hpp"

namespace ioport {

class BlockingLink {
  public:
    explicit BlockingLink(LinkSettings settings) : link_(io_.get_executor(), std::move(settings)) {}

    Result<> open() { return link_.open(); }
    void close() { link_.close(); }
    bool is_open() const { return link_.is_open(); }
    bool low_latency() const { return link_.low_latency(); }
    const LinkSettings& settings() const { return link_.settings(); }
    std::chrono::microseconds last_round_trip() const { return link_.last_round_trip(); }

    // One transaction with the link's retries; returns when it succeeded or finally failed.
    Result<Reading> transact(const Exchange& exchange);

  private:
    asio::io_context io_;
    SerialLink link_;
};

}  // namespace ioport
