// What the watchdog sees of a link's loop (LinkScheduler::progressing), against a device the
// test scripts on a pty, with the time to judge given by the test: a loop that stops acting is
// stuck one timeout and the slack later, and a loop that keeps acting through the longest steps
// a noisy line causes never is.
#include <gtest/gtest.h>

#include "daemon/core/link_scheduler.hpp"
#include "tests/support/pty_pair.hpp"
#include "tests/support/timing.hpp"

namespace ioport::daemon {
namespace {

using test::PtyDevice;
using test::run_until;

config::LinkConfig hub_link(const std::string& device, std::chrono::microseconds timeout) {
    config::LinkConfig link;
    link.name = "hub0";
    link.device = device;
    link.timeout = timeout;
    link.retries = 10;  // the most the configuration allows
    link.modules = {config::ModuleConfig{.address = {ModuleType::dim16, 0}}};
    return link;
}

class LinkWatchdog : public ::testing::Test {
  protected:
    // A module that never answers.
    void SetUp() override {
        device.serve([](const std::string&) { return std::vector<test::Reply>{}; });
    }
    asio::io_context io;
    PtyDevice device{io};
    Log log{Log::Target::standard_error, config::LogLevel::off};
    EventBus bus;
};

TEST_F(LinkWatchdog, ALoopThatStopsActingIsStuckOneTimeoutAndTheSlackLater) {
    const auto timeout = 200ms;
    auto link = std::make_shared<LinkScheduler>(io.get_executor(), hub_link(device.path(), timeout),
                                                log, bus);
    const auto before = Clock::now();
    link->start();
    ASSERT_TRUE(run_until(io, [&] { return !device.requests().empty(); }));
    const auto seen = Clock::now();
    // From here nothing runs: the loop waits for an answer whose timeout never fires, as a hung
    // loop would.
    EXPECT_TRUE(link->progressing(before + timeout + watchdog_slack - 1ms));
    EXPECT_FALSE(link->progressing(seen + timeout + watchdog_slack));
    link->stop();
}

// The old bound, (retries + 1) timeouts + 10 timeouts + 1 s, was 2.05 s here; a step on this
// line takes 11 × (10 timeouts of noise + 1): 5.5 s. Every moment of it is progress.
TEST_F(LinkWatchdog, ALoopOnAChatteringLineIsNeverStuck) {
    // Stretched where the test runs slower (under qemu-user a starved test stalled past 50 ms).
    const auto timeout = 50ms * test::slowdown;
    auto link = std::make_shared<LinkScheduler>(io.get_executor(), hub_link(device.path(), timeout),
                                                log, bus);
    // The line chatters from before the start (a byte every 5 ms), so that the link's first
    // request already meets it.
    asio::steady_timer chatter(io);
    std::function<void()> noise = [&] {
        device.send("#");
        chatter.expires_after(5ms);
        chatter.async_wait([&](const boost::system::error_code& ec) {
            if (!ec) noise();
        });
    };
    noise();
    link->start();
    // Measured once the link has met the chatter (an answer of its was noise): the kernel hands
    // a pty's bytes to the reader through a worker thread, which beside busy loops runs late
    // (seen: 4 s), and until then the line the link reads is silent.
    ASSERT_TRUE(run_until(
        io, [&] { return link->counters().bad_answer > 0; }, 10s * test::slowdown));
    const auto end = Clock::now() + 3s;
    int checks = 0;
    while (Clock::now() < end) {
        io.run_for(20ms);
        ASSERT_TRUE(link->progressing(Clock::now())) << "stuck after " << checks * 20 << " ms";
        ++checks;
    }
    // How often the link found the line silent is not counted: whenever that worker runs late,
    // the line the link reads falls silent where the test's writes never did, and each such
    // silence lets one more attempt go out.
    chatter.cancel();
    link->stop();
}

}  // namespace
}  // namespace ioport::daemon
