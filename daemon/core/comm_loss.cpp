#include "daemon/core/comm_loss.hpp"

#include <fmt/format.h>

#include "config/duration.hpp"

namespace ioport::daemon {

CommLossWatch::CommLossWatch(const asio::any_io_executor& executor, Log& log, EventBus& bus,
                             std::function<void()> lost)
    : log_(log), bus_(bus), on_lost_(std::move(lost)), timer_(executor) {}

void CommLossWatch::start(std::chrono::microseconds timeout) {
    timeout_ = timeout;
    last_contact_ = Clock::now();  // a loss counts from start-up too
    arm();
}

void CommLossWatch::set_timeout(std::chrono::microseconds timeout) {
    timeout_ = timeout;
    if (armed_)
        timer_.cancel();  // armed again with the new timeout, or not at all
    else
        arm();
}

void CommLossWatch::stop() {
    stopped_ = true;
    timer_.cancel();
}

void CommLossWatch::answered() {
    lost_ = false;
    arm();
}

void CommLossWatch::arm() {
    if (armed_ || lost_ || stopped_ || timeout_.count() == 0) return;
    armed_ = true;
    timer_.expires_at(last_contact_ + timeout_);
    timer_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        if (const auto self = weak.lock()) self->due(ec);
    });
}

void CommLossWatch::due(const boost::system::error_code& ec) {
    armed_ = false;
    // Cancelled by a reload that changed the timeout (or by the stop): armed anew, or not.
    if (ec || Clock::now() < last_contact_ + timeout_) {
        arm();
        return;
    }
    if (timeout_.count() == 0 || stopped_) return;
    lost_ = true;
    const auto text = fmt::format(
        "no Modbus request from any client for {}: every output module is sent its safe value "
        "and keeps it until a client writes it",
        format_duration(timeout_));
    log_.warn({.comm_loss = true}, "{}", text);
    bus_.publish(Note{.kind = EventKind::comm_loss, .text = text});
    if (on_lost_) on_lost_();
}

}  // namespace ioport::daemon
