// Communication loss (gateway.md §5.3): when no client request that shows a SCADA is there has
// come for modbus.comm_loss_timeout, every output module is sent its safe value and keeps it
// until a client writes it. The gateway's policy, so the core's: the Modbus server tells it of
// each such request (contact(), answered()) and shows lost() in register 1020; the gateway
// decides what a loss does (the links' safe state).
//
// The timer is armed lazily, as the connections' watchdogs are: a request only moves the time of
// the last contact, and the timer, when it fires early, is armed again for what is left.
#pragma once

#include <chrono>
#include <functional>
#include <memory>

#include "daemon/base/log.hpp"
#include "daemon/core/bus.hpp"
#include "daemon/core/poll_plan.hpp"  // Clock
#include "link/asio.hpp"

namespace ioport::daemon {

class CommLossWatch : public std::enable_shared_from_this<CommLossWatch> {
  public:
    // `lost`: called when the loss is declared (logged and told to the bus first); not again
    // until a request has come.
    CommLossWatch(const asio::any_io_executor& executor, Log& log, EventBus& bus,
                  std::function<void()> lost);

    // From now, with this timeout (0: off); again by a reload, which keeps the last contact.
    void start(std::chrono::microseconds timeout);
    void set_timeout(std::chrono::microseconds timeout);
    void stop();

    // A request that keeps contact arrived at `at`, and later was answered: the first answer
    // after a loss still showed it (register 1020 read 1); from then on it is over.
    void contact(Clock::time_point at) { last_contact_ = at; }
    void answered();

    // A loss is in effect: declared, and no request answered since.
    bool lost() const { return lost_; }

  private:
    void arm();
    void due(const boost::system::error_code& ec);

    Log& log_;
    EventBus& bus_;
    std::function<void()> on_lost_;
    asio::steady_timer timer_;
    std::chrono::microseconds timeout_{0};
    Clock::time_point last_contact_ = Clock::now();
    bool armed_ = false;
    bool lost_ = false;
    bool stopped_ = false;
};

}  // namespace ioport::daemon
