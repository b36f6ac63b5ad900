// The simulator keeps the line's time: an answer never comes sooner than the modelled wire time
// allows, less the most its answer clock sets a timer early (sim/answer_clock.hpp), and every
// answer is counted in the errors a benchmark reports.
#include <gtest/gtest.h>

#include <algorithm>

#include "link/serial_link.hpp"
#include "sim/simulator.hpp"
#include "tests/support/process.hpp"
#include "tests/support/pty_pair.hpp"
#include "tests/support/timing.hpp"

namespace ioport {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

TEST(SimulatorTiming, AnswersNoSoonerThanTheModelledLineAllows) {
    constexpr int baud = 38400;
    constexpr int transactions = 100;
    const ModuleAddress polled{ModuleType::dim16, 0};
    asio::io_context io;
    test::TempDir dir;
    sim::DeviceModel model(sim::Protocol::ioport, 1);
    ASSERT_TRUE(model.add(polled));
    sim::SimulatorSettings settings;
    settings.link_path = dir / "tty";
    settings.baud = baud;
    settings.turnaround = 500us;
    sim::Simulator simulator(io, model, settings);
    ASSERT_TRUE(simulator.start());
    // The timeout only bounds a lost answer; what is measured is how soon the answers come.
    SerialLink link(io.get_executor(), {settings.link_path, baud, 100ms * test::slowdown, 0});
    ASSERT_TRUE(link.open());

    // "a0\r" takes 3 characters, the answer "XXXX\r" 5, at 10 bits each.
    const auto modelled = std::chrono::microseconds{8 * 10 * 1'000'000 / baud} + 500us;
    const auto soonest = modelled - sim::AnswerClock::max_advance - 2us;  // 2 µs: rounding
    std::vector<Clock::duration> round_trips;
    test::run_until_done(io, [&]() -> asio::awaitable<void> {
        for (int i = 0; i < transactions; ++i) {
            const auto start = Clock::now();
            const auto reading = co_await link.transact(*make_exchange(polled));
            EXPECT_TRUE(reading) << reading.error().message;
            round_trips.push_back(Clock::now() - start);
        }
    });

    ASSERT_EQ(round_trips.size(), static_cast<std::size_t>(transactions));
    const auto quickest = *std::min_element(round_trips.begin(), round_trips.end());
    EXPECT_GE(quickest, soonest) << "the simulator answered before the line could have";
    EXPECT_EQ(simulator.answer_errors().count(), static_cast<std::uint64_t>(transactions));
    EXPECT_GE(simulator.answer_errors().quantile(0.0), -sim::AnswerClock::max_advance);
}

}  // namespace
}  // namespace ioport
