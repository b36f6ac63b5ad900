#include <gtest/gtest.h>

#include "sim/control.hpp"

namespace ioport::sim {
namespace {

using namespace std::chrono_literals;

class ControlTest : public ::testing::Test {
  protected:
    DeviceModel hub{Protocol::ioport, 1};
    DeviceModel id2{Protocol::id2, 1};
    std::string run(DeviceModel& model, std::string_view line) { return execute(model, line).text; }
};

TEST_F(ControlTest, ModulesSetGet) {
    EXPECT_EQ(run(hub, "add dim16:0"), "ok\n");
    EXPECT_EQ(run(hub, "add acm3p:1"), "ok\n");
    EXPECT_EQ(run(hub, "modules"), "dim16:0\nacm3p:1\nok\n");
    EXPECT_EQ(run(hub, "set dim16:0 0x8000"), "ok\n");
    EXPECT_EQ(run(hub, "get dim16:0"), "32768\nok\n");
    EXPECT_EQ(run(hub, "set acm3p:1 1 2 65535"), "ok\n");
    EXPECT_EQ(run(hub, "get acm3p:1"), "1 2 65535\nok\n");
    EXPECT_EQ(run(hub, "remove acm3p:1"), "ok\n");
    EXPECT_EQ(run(hub, "modules"), "dim16:0\nok\n");
}

TEST_F(ControlTest, ErrorsSayWhatIsWrong) {
    EXPECT_TRUE(run(hub, "set dim16:0 1").starts_with("error dim16 0 is not on this hub"));
    EXPECT_TRUE(run(hub, "set dim16:0 65536").starts_with("error '65536' is not a value"));
    EXPECT_TRUE(run(hub, "frobnicate").starts_with("error unknown command"));
    EXPECT_TRUE(run(hub, "").starts_with("error empty command"));
    EXPECT_TRUE(run(hub, "fault dim16:0 explode").starts_with("error unknown fault"));
    EXPECT_TRUE(run(hub, "fault all delay").starts_with("error a delay fault needs a duration"));
    EXPECT_TRUE(run(hub, "fault all silent 1.5").starts_with("error '1.5' is neither"));
    EXPECT_TRUE(
        run(hub, "fault all delay 5parsecs").starts_with("error '5parsecs' is not a duration"));
    EXPECT_TRUE(run(hub, "get stop").starts_with("error"));
    EXPECT_TRUE(run(id2, "add dim16:0").starts_with("error this simulator is an ID-2"));
}

TEST_F(ControlTest, FaultsWithProbabilityAndDelay) {
    EXPECT_EQ(run(hub, "add dim16:0"), "ok\n");
    EXPECT_EQ(run(hub, "fault dim16:0 delay 150ms"), "ok\n");
    const auto answers = hub.receive("a0\r", 0us);
    ASSERT_EQ(answers.size(), 1u);
    EXPECT_EQ(answers[0].extra_delay, 150ms);
    EXPECT_EQ(run(hub, "fault all silent 0"), "ok\n");  // probability 0: never
    EXPECT_EQ(hub.receive("a0\r", 0us).size(), 1u);
    EXPECT_EQ(run(hub, "fault all silent"), "ok\n");
    EXPECT_TRUE(hub.receive("a0\r", 0us).empty());
}

TEST_F(ControlTest, Id2Commands) {
    EXPECT_EQ(run(id2, "set stop 1"), "ok\n");
    EXPECT_EQ(run(id2, "get stop"), "1\nok\n");
    EXPECT_EQ(run(id2, "set count 65535"), "ok\n");
    EXPECT_TRUE(run(id2, "set count 65536").starts_with("error"));
    EXPECT_EQ(run(id2, "pulse 2"), "ok\n");
    EXPECT_EQ(run(id2, "get count"), "1\nok\n");
}

TEST_F(ControlTest, LogAndPortActions) {
    EXPECT_EQ(run(hub, "add dim16:0"), "ok\n");
    (void)hub.receive("a0\ra7\r", 5us);
    EXPECT_EQ(run(hub, "log"), "5 a0 0000\n5 a7 -\nok 2\n");
    EXPECT_EQ(run(hub, "log clear"), "ok\n");
    EXPECT_EQ(run(hub, "log"), "ok 0\n");
    (void)hub.receive("a0\r", 7us);
    EXPECT_EQ(run(hub, "log take"), "7 a0 0000\nok 1\n");  // read and cleared in one step
    EXPECT_EQ(run(hub, "log"), "ok 0\n");
    EXPECT_EQ(run(hub, "log drop"), "error log takes nothing, 'clear' or 'take'\n");
    EXPECT_EQ(run(hub, "fault dim16:0 garbage"), "ok\n");
    (void)hub.receive("a0\ra0\r", 9us);
    EXPECT_EQ(run(hub, "faults"), "silent 0 error-ack 0 garbage 2 short 0 long 0 delay 0\nok\n");
    const auto unplug = execute(hub, "unplug 2s");
    ASSERT_TRUE(unplug.action);
    EXPECT_EQ(unplug.action->kind, PortAction::Kind::unplug);
    EXPECT_EQ(unplug.action->after, 2s);
    EXPECT_EQ(execute(hub, "replug").action->kind, PortAction::Kind::replug);
    EXPECT_FALSE(execute(hub, "unplug soon").action);
    const auto chatter = execute(hub, "chatter 5ms");
    ASSERT_TRUE(chatter.action);
    EXPECT_EQ(chatter.action->kind, PortAction::Kind::chatter);
    EXPECT_EQ(chatter.action->after, 5ms);
    const auto quiet = execute(hub, "chatter off");
    ASSERT_TRUE(quiet.action);
    EXPECT_EQ(quiet.action->kind, PortAction::Kind::chatter);
    EXPECT_FALSE(quiet.action->after);
    EXPECT_TRUE(run(hub, "chatter 0s").starts_with("error '0s' is not an interval"));
    EXPECT_TRUE(run(hub, "chatter").starts_with("error chatter takes an interval"));
}

// An ID-2 whose counter stops answering while its stop input still does.
TEST_F(ControlTest, AnId2CommandCanFailAlone) {
    EXPECT_EQ(run(id2, "set count 7"), "ok\n");
    EXPECT_EQ(run(id2, "fault C silent"), "ok\n");
    auto answers = id2.receive("IC", 0us);
    ASSERT_EQ(answers.size(), 1u);
    EXPECT_EQ(answers[0].bytes, "0\n");
    EXPECT_EQ(run(id2, "fault R error-ack"), "ok\n");
    answers = id2.receive("R", 0us);
    ASSERT_EQ(answers.size(), 1u);
    EXPECT_EQ(id2.counter(), 7) << "a reset answered with an error ack changed the counter";
    EXPECT_EQ(run(id2, "fault device none"), "ok\n");
    EXPECT_EQ(id2.receive("IC", 0us).size(), 2u);
    EXPECT_TRUE(run(id2, "fault X silent").starts_with("error an ID-2 takes: fault device|I|C|R"));
    EXPECT_TRUE(run(hub, "fault C silent").starts_with("error"));
}

}  // namespace
}  // namespace ioport::sim
