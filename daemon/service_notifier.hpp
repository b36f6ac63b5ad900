// systemd's service protocol (sd_notify): READY=1 once started, STATUS= kept current,
// WATCHDOG=1 at a quarter of WatchdogSec while the gateway is healthy, STOPPING=1 on shutdown.
// Without NOTIFY_SOCKET every notification is a no-op, so ioportd runs the same without systemd.
#pragma once

#include <chrono>
#include <functional>
#include <string>

#include "daemon/base/log.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

class ServiceNotifier {
  public:
    // `status`: the one-line summary; `healthy`: whether the watchdog may be fed now.
    ServiceNotifier(const asio::any_io_executor& executor, std::function<std::string()> status,
                    std::function<bool()> healthy, Log& log);

    void ready();
    // A reload has begun; ready() again when it is over, whatever its outcome.
    void reloading();
    void stopping();

  private:
    asio::awaitable<void> keep_informed();
    void notify(const std::string& state);

    asio::steady_timer timer_;
    std::function<std::string()> status_;
    std::function<bool()> healthy_;
    Log& log_;
    std::chrono::microseconds watchdog_{0};
    std::string last_status_;
    bool stopping_ = false;
    bool informing_ = false;  // keep_informed() is running
};

}  // namespace ioport::daemon
