// The simulator keeps its model's time although its timers wake late: it learns how late, sets
// them that much early, and says how well it did.
#include <gtest/gtest.h>

#include "sim/answer_clock.hpp"

namespace ioport::sim {
namespace {

using namespace std::chrono_literals;

TEST(AnswerErrors, QuantilesAreNearestRankToTheMicrosecond) {
    AnswerErrors errors;
    EXPECT_EQ(errors.quantile(0.5), 0us);  // none yet
    for (const auto error : {20us, -5us, 10us, 0us})
        errors.add(error);
    EXPECT_EQ(errors.count(), 4U);
    EXPECT_EQ(errors.quantile(0.0), -5us);
    EXPECT_EQ(errors.quantile(0.25), -5us);
    EXPECT_EQ(errors.quantile(0.5), 0us);
    EXPECT_EQ(errors.quantile(0.75), 10us);
    EXPECT_EQ(errors.quantile(0.9), 20us);
    EXPECT_EQ(errors.quantile(1.0), 20us);
}

TEST(AnswerErrors, EarlyByPartOfAMicrosecondCountsAsOneEarly) {
    AnswerErrors errors;
    errors.add(-500ns);
    errors.add(999ns);
    EXPECT_EQ(errors.quantile(0.0), -1us);
    EXPECT_EQ(errors.quantile(1.0), 0us);
}

TEST(AnswerErrors, ErrorsBeyondTheRangeFallIntoItsEnds) {
    AnswerErrors errors;
    errors.add(-1s);
    errors.add(1s);
    EXPECT_EQ(errors.quantile(0.0), -256us);
    EXPECT_EQ(errors.quantile(1.0), 1791us);
}

// A machine whose timers wake `lateness` after they expire: the answer goes out that much after
// the time the simulator set, which is the modelled end less the advance.
std::chrono::nanoseconds answer_on(AnswerClock& clock, std::chrono::nanoseconds lateness) {
    const auto error = lateness - clock.advance();
    clock.answered(error);
    return error;
}

TEST(AnswerClock, LearnsAConstantLatenessAndThenAnswersOnTime) {
    AnswerClock clock;
    EXPECT_EQ(clock.advance(), 0ns);
    for (int i = 0; i < 100; ++i)
        (void)answer_on(clock, 35us);
    EXPECT_GE(clock.advance(), 35us - AnswerClock::step);
    EXPECT_LE(clock.advance(), 35us + AnswerClock::step);
    for (int i = 0; i < 100; ++i) {
        const auto error = answer_on(clock, 35us);
        EXPECT_LE(error, AnswerClock::step);
        EXPECT_GE(error, -AnswerClock::step);
    }
}

TEST(AnswerClock, FollowsTheMedianNotTheTail) {
    // Nine answers in ten wake 30 µs late, one in ten 2 ms late: the advance stays near 30 µs.
    AnswerClock clock;
    for (int i = 0; i < 1000; ++i)
        (void)answer_on(clock, i % 10 == 9 ? 2ms : 30us);
    EXPECT_GE(clock.advance(), 29us);
    EXPECT_LE(clock.advance(), 31us);
    EXPECT_EQ(clock.errors().quantile(0.5), 0us);
}

TEST(AnswerClock, AdvancesNoFurtherThanItsMaximumAndNeverBelowZero) {
    AnswerClock clock;
    for (int i = 0; i < 1000; ++i)
        (void)answer_on(clock, 5ms);  // a machine too busy: no advance could be right
    EXPECT_EQ(clock.advance(), AnswerClock::max_advance);
    for (int i = 0; i < 1000; ++i)
        (void)answer_on(clock, 0ns);  // and the load is gone: back to no advance
    EXPECT_EQ(clock.advance(), 0ns);
    clock.answered(-10us);
    EXPECT_EQ(clock.advance(), 0ns);
}

TEST(AnswerClock, ClearingErrorsKeepsWhatItLearnt) {
    AnswerClock clock;
    for (int i = 0; i < 100; ++i)
        (void)answer_on(clock, 20us);
    const auto learnt = clock.advance();
    clock.clear_errors();
    EXPECT_EQ(clock.errors().count(), 0U);
    EXPECT_EQ(clock.advance(), learnt);
}

}  // namespace
}  // namespace ioport::sim
