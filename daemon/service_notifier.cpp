#include "daemon/service_notifier.hpp"

#include <systemd/sd-daemon.h>

#include <utility>

namespace ioport::daemon {
namespace {

using namespace std::chrono_literals;

// How often STATUS= is brought up to date when there is no watchdog to feed more often.
constexpr auto status_period = 1s;

}  // namespace

ServiceNotifier::ServiceNotifier(const asio::any_io_executor& executor,
                                 std::function<std::string()> status, std::function<bool()> healthy,
                                 Log& log)
    : timer_(executor), status_(std::move(status)), healthy_(std::move(healthy)), log_(log) {
    std::uint64_t usec = 0;
    if (sd_watchdog_enabled(0, &usec) > 0) watchdog_ = std::chrono::microseconds(usec);
}

void ServiceNotifier::notify(const std::string& state) {
    if (sd_notify(0, state.c_str()) < 0) log_.debug({}, "sd_notify({}) failed", state);
}

void ServiceNotifier::ready() {
    last_status_ = status_();
    notify("READY=1\nSTATUS=" + last_status_);
    if (!std::exchange(informing_, true))
        asio::co_spawn(timer_.get_executor(), keep_informed(), asio::detached);
}

void ServiceNotifier::reloading() {
    notify("RELOADING=1\nSTATUS=reloading the configuration");
}

void ServiceNotifier::stopping() {
    stopping_ = true;
    timer_.cancel();
    notify("STOPPING=1\nSTATUS=stopping");
}

asio::awaitable<void> ServiceNotifier::keep_informed() {
    // A quarter of the watchdog period leaves three chances before systemd gives up on us.
    const auto period = watchdog_.count() > 0
                            ? std::min<std::chrono::microseconds>(watchdog_ / 4, status_period)
                            : std::chrono::microseconds(status_period);
    while (!stopping_) {
        timer_.expires_after(period);
        boost::system::error_code ec;
        co_await timer_.async_wait(asio::redirect_error(asio::use_awaitable, ec));
        if (stopping_) break;
        if (auto status = status_(); status != last_status_) {
            last_status_ = std::move(status);
            notify("STATUS=" + last_status_);
        }
        // Fed only while every link makes progress: a stuck poll loop lets systemd restart us.
        if (watchdog_.count() > 0 && healthy_()) notify("WATCHDOG=1");
    }
}

}  // namespace ioport::daemon
