// When Home Assistant's birth (`<discovery_prefix>/status` = online) is served (gateway.md §7.3,
// §7.5): at once, then at most once every `interval`; births within it are served by one
// republication when it ends. Any client of the broker can publish a birth, and each one served
// republishes every discovery config and state: 295 births in 6 s once made 710 messages of
// 207 kB for five modules, and a large gateway would send a thousand configs a second.
//
// The time is the caller's: pure, and tested without waiting (tests/unit/mqtt_json_test.cpp).
#pragma once

#include <chrono>
#include <optional>

namespace ioport::daemon {

class BirthPacer {
  public:
    using Clock = std::chrono::steady_clock;

    explicit BirthPacer(Clock::duration interval) : interval_(interval) {}

    // A birth arrived: true when it is to be served now; false when one was served less than
    // `interval` ago, and then one republication is due when that interval ends (due()).
    bool asked(Clock::time_point now) {
        if (!served_ || now - *served_ >= interval_) {
            served_ = now;
            waiting_ = false;
            return true;
        }
        waiting_ = true;
        return false;
    }

    // True once when a held-back birth's time has come; it counts as served then, so the next
    // birth waits for a whole interval again.
    bool due(Clock::time_point now) {
        if (!waiting_ || now - *served_ < interval_) return false;
        waiting_ = false;
        served_ = now;
        return true;
    }

    // When a held-back birth is due; nullopt: none is waiting.
    std::optional<Clock::time_point> due_at() const {
        if (!waiting_) return std::nullopt;
        return *served_ + interval_;
    }

  private:
    Clock::duration interval_;
    std::optional<Clock::time_point> served_;
    bool waiting_ = false;
};

}  // namespace ioport::daemon
