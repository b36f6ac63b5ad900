// The order of work on a link (gateway.md §4): client writes, then due refreshes, then poll
// reads in round-robin; back-off of failing modules; what counts as a poll cycle.
#include "daemon/core/poll_plan.hpp"

#include <gtest/gtest.h>

namespace ioport::daemon {
namespace {

using Kind = PollPlan::Kind;

const PollEntry input{false, 0us};
const PollEntry output{true, 1s};

struct PollPlanTest : ::testing::Test {
    Clock::time_point t0 = Clock::time_point{} + 1h;
};

// Does what the plan says until it is idle or `limit` steps were taken, all succeeding at `now`;
// returns the entries in the order they were served ("p2" poll of entry 2, "r1" refresh).
std::string drive(PollPlan& plan, Clock::time_point now, int limit) {
    std::string order;
    for (int i = 0; i < limit; ++i) {
        const auto step = plan.next(now, false);
        if (step.kind == Kind::idle) break;
        order.append(step.kind == Kind::poll ? "p" : "r").append(std::to_string(step.entry)) += ' ';
        plan.done(step.entry, true, now);
    }
    return order;
}

TEST_F(PollPlanTest, OutputsAreRestoredFirstThenInputsInRoundRobin) {
    PollPlan plan({input, output, input, output});
    plan.port_opened(t0);
    EXPECT_EQ(drive(plan, t0, 6), "r1 r3 p0 p2 p0 p2 ");
}

TEST_F(PollPlanTest, APendingWriteGoesBeforeEverything) {
    PollPlan plan({input, output});
    plan.port_opened(t0);
    EXPECT_EQ(plan.next(t0, true).kind, Kind::write);
    EXPECT_EQ(plan.next(t0, false).kind, Kind::refresh);
}

// gateway.md §4: after a write, a waiting refresh or poll read goes before the next write, so a
// stream of writes (to a dead module, each failing slowly) never starves polling.
TEST_F(PollPlanTest, WritesTakeTurnsWithDueWorkButNeverWait) {
    PollPlan plan({input, output, input});
    plan.port_opened(t0);
    std::string order;
    for (int i = 0; i < 8; ++i) {
        const auto step = plan.next(t0, true);
        if (step.kind == Kind::write) {
            order += "w ";
            plan.done(1, false, t0);  // the write to the output module failed
            continue;
        }
        order.append(step.kind == Kind::poll ? "p" : "r").append(std::to_string(step.entry)) += ' ';
        plan.done(step.entry, true, t0);
    }
    // The refresh backs off after the failed writes; the inputs are served every other step.
    EXPECT_EQ(order, "w p0 w p2 w p0 w p2 ");
    // With nothing due, writes follow each other at once.
    PollPlan idle({PollEntry{false, 1s}});
    idle.port_opened(t0);
    idle.done(0, true, t0);
    EXPECT_EQ(idle.next(t0, true).kind, Kind::write);
    EXPECT_EQ(idle.next(t0, true).kind, Kind::write);
}

// gateway.md §4: while writes keep coming, the turns between them alternate between due
// refreshes and due poll reads, so outputs that are always due to refresh (many of them, one
// dead and slow) never take every turn from the inputs.
TEST_F(PollPlanTest, TurnsBetweenWritesAlternateBetweenRefreshesAndPollReads) {
    const PollEntry fast_output{true, 1ms};  // due again by the time its turn ends
    PollPlan plan({input, fast_output, fast_output, fast_output, input});
    plan.port_opened(t0);
    std::string order;
    auto now = t0;
    for (int i = 0; i < 16; ++i) {
        const auto step = plan.next(now, true);
        now += 10ms;  // every step takes time: each refresh is due again after it
        if (step.kind == Kind::write) {
            order += "w ";
            continue;
        }
        order.append(step.kind == Kind::poll ? "p" : "r").append(std::to_string(step.entry)) += ' ';
        plan.done(step.entry, true, now);
    }
    EXPECT_EQ(order, "w r1 w p0 w r2 w p4 w r3 w p0 w r1 w p4 ");
    // Without writes, due refreshes still go before poll reads.
    EXPECT_EQ(plan.next(now, false).kind, Kind::refresh);
}

TEST_F(PollPlanTest, ADueRefreshGoesBeforePollReads) {
    PollPlan plan({input, input, output});
    plan.port_opened(t0);
    EXPECT_EQ(drive(plan, t0, 3), "r2 p0 p1 ");
    // One second later the refresh is due again and jumps ahead of the round-robin.
    const auto later = t0 + 1s;
    EXPECT_EQ(drive(plan, later, 3), "r2 p0 p1 ");
}

TEST_F(PollPlanTest, RefreshIsNotDueBeforeItsInterval) {
    PollPlan plan({output});
    plan.port_opened(t0);
    EXPECT_EQ(drive(plan, t0, 5), "r0 ");
    const auto step = plan.next(t0 + 999ms, false);
    EXPECT_EQ(step.kind, Kind::idle);
    EXPECT_EQ(step.wake_at, t0 + 1s);
}

TEST_F(PollPlanTest, PollIntervalIsHonoured) {
    PollPlan plan({input, PollEntry{false, 200ms}});
    plan.port_opened(t0);
    EXPECT_EQ(drive(plan, t0, 4), "p0 p1 p0 p0 ");
    EXPECT_EQ(drive(plan, t0 + 200ms, 2), "p1 p0 ");
}

TEST_F(PollPlanTest, AFailingModuleBacksOffWhileTheOthersAreStillPolled) {
    PollPlan plan({input, input});
    plan.port_opened(t0);
    auto step = plan.next(t0, false);
    ASSERT_EQ(step.entry, 0u);
    plan.done(0, false, t0);  // entry 0 is dead
    EXPECT_EQ(drive(plan, t0, 3), "p1 p1 p1 ");
    EXPECT_EQ(drive(plan, t0 + 249ms, 1), "p1 ");
    EXPECT_EQ(drive(plan, t0 + 250ms, 2), "p0 p1 ");
}

TEST(Backoff, DoublesFrom250msUpTo4s) {
    EXPECT_EQ(backoff(0), 0us);
    EXPECT_EQ(backoff(1), 250ms);
    EXPECT_EQ(backoff(2), 500ms);
    EXPECT_EQ(backoff(3), 1s);
    EXPECT_EQ(backoff(5), 4s);
    EXPECT_EQ(backoff(50), 4s);
}

TEST_F(PollPlanTest, ReopeningRestartsBackoffAndRestoresOutputs) {
    PollPlan plan({input, output});
    plan.port_opened(t0);
    plan.done(0, false, t0);
    plan.done(0, false, t0);
    plan.done(1, true, t0);
    plan.port_opened(t0 + 10ms);
    EXPECT_EQ(drive(plan, t0 + 10ms, 2), "r1 p0 ");
}

TEST_F(PollPlanTest, ACycleIsOnePassOverTheModules) {
    PollPlan plan({input, input});
    plan.port_opened(t0);
    EXPECT_EQ(plan.cycles(), 0u);
    drive(plan, t0, 2);
    (void)plan.next(t0 + 5ms, false);  // wraps: the first pass is complete
    EXPECT_EQ(plan.cycles(), 1u);
    plan.done(0, true, t0 + 5ms);
    plan.done(1, true, t0 + 5ms);
    drive(plan, t0 + 12ms, 1);
    (void)plan.next(t0 + 12ms, false);
    EXPECT_EQ(plan.cycles(), 2u);
    EXPECT_EQ(plan.last_cycle(), 7ms);
}

TEST_F(PollPlanTest, AnIdlePassIsNoCycle) {
    PollPlan plan({PollEntry{false, 1s}});
    plan.port_opened(t0);
    drive(plan, t0, 1);
    for (int i = 0; i < 5; ++i)
        EXPECT_EQ(plan.next(t0 + 10ms, false).kind, Kind::idle);
    EXPECT_EQ(plan.cycles(), 1u);
}

TEST_F(PollPlanTest, NoEntriesIsAlwaysIdle) {
    PollPlan plan({});
    plan.port_opened(t0);
    const auto step = plan.next(t0, false);
    EXPECT_EQ(step.kind, Kind::idle);
    EXPECT_EQ(step.wake_at, Clock::time_point::max());
}

}  // namespace
}  // namespace ioport::daemon
