// The simulated devices answer like the real ones, and their faults do what they say.
#include <gtest/gtest.h>

#include "sim/model.hpp"

namespace ioport::sim {
namespace {

using namespace std::chrono_literals;

class HubModelTest : public ::testing::Test {
  protected:
    HubModelTest() : hub(Protocol::ioport, 7) {
        for (const auto* m : {"dim16:0", "dom16:0", "acm3p:1", "rgbdm:2", "mux8m:0"})
            EXPECT_TRUE(hub.add(*parse_module_address(m)));
    }
    std::vector<std::string> send(std::string_view bytes) {
        std::vector<std::string> replies;
        for (auto& answer : hub.receive(bytes, 0us))
            replies.push_back(answer.bytes);
        return replies;
    }
    DeviceModel hub;
};

using Replies = std::vector<std::string>;

TEST_F(HubModelTest, AnswersReadsWithTheInputsSet) {
    const std::array<std::uint16_t, 3> acm{13208, 41203, 4095};
    ASSERT_TRUE(hub.set_values({ModuleType::acm3p, 1}, acm));
    ASSERT_TRUE(hub.set_values({ModuleType::dim16, 0}, std::array<std::uint16_t, 1>{0x8000}));
    EXPECT_EQ(send("c1\ra0\r"), (Replies{"3398A0F30FFF\r", "8000\r"}));
}

TEST_F(HubModelTest, RequestsMaySplitAcrossReads) {
    EXPECT_TRUE(send("a").empty());
    EXPECT_EQ(send("0\r"), Replies{"0000\r"});
}

TEST_F(HubModelTest, AppliesAcknowledgedCommands) {
    EXPECT_EQ(send("b093D1\rf2R\ri005\r"), (Replies{"1\r", "1\r", "1\r"}));
    EXPECT_EQ(hub.values({ModuleType::dom16, 0})->front(), 0x93D1);
    EXPECT_EQ(hub.values({ModuleType::rgbdm, 2})->front(), 1);
    EXPECT_EQ(hub.values({ModuleType::mux8m, 0})->front(), 0x0005);
}

TEST_F(HubModelTest, IsSilentForAbsentModulesAndMalformedRequests) {
    EXPECT_TRUE(send("a1\r").empty());           // not on the hub
    EXPECT_TRUE(send("b093G1\r").empty());       // not hex
    EXPECT_TRUE(send("f2X\r").empty());          // no such colour
    EXPECT_TRUE(send("a0a0a0a0a0\r").empty());   // noise longer than any request
    EXPECT_EQ(send("a0\r"), Replies{"0000\r"});  // and back in step
}

TEST_F(HubModelTest, ErrorAckLeavesTheOutputUnchanged) {
    ASSERT_TRUE(hub.set_fault({ModuleType::dom16, 0}, {FaultKind::error_ack, 1.0, {}}));
    EXPECT_EQ(send("b0FFFF\r"), Replies{"0\r"});
    EXPECT_EQ(hub.values({ModuleType::dom16, 0})->front(), 0);
}

TEST_F(HubModelTest, EachFaultKind) {
    const ModuleAddress dim{ModuleType::dim16, 0};
    ASSERT_TRUE(hub.set_values(dim, std::array<std::uint16_t, 1>{0x1234}));
    ASSERT_TRUE(hub.set_fault(dim, {FaultKind::silent, 1.0, {}}));
    EXPECT_TRUE(send("a0\r").empty());
    ASSERT_TRUE(hub.set_fault(dim, {FaultKind::short_reply, 1.0, {}}));
    EXPECT_EQ(send("a0\r"), Replies{"123\r"});
    ASSERT_TRUE(hub.set_fault(dim, {FaultKind::long_reply, 1.0, {}}));
    EXPECT_EQ(send("a0\r"), Replies{"12340\r"});
    ASSERT_TRUE(hub.set_fault(dim, {FaultKind::garbage, 1.0, {}}));
    const auto garbage = send("a0\r");
    ASSERT_EQ(garbage.size(), 1u);
    EXPECT_EQ(garbage[0].back(), '\r');
    EXPECT_EQ(garbage[0].find_first_of("0123456789ABCDEFabcdef"), std::string::npos);
    ASSERT_TRUE(hub.set_fault(dim, {FaultKind::delay, 1.0, 150ms}));
    const auto late = hub.receive("a0\r", 0us);
    ASSERT_EQ(late.size(), 1u);
    EXPECT_EQ(late[0].bytes, "1234\r");
    EXPECT_EQ(late[0].extra_delay, 150ms);
    ASSERT_TRUE(hub.set_fault(dim, {FaultKind::none, 1.0, {}}));
    EXPECT_EQ(send("a0\r"), Replies{"1234\r"});
}

TEST_F(HubModelTest, ProbabilisticFaultsHitAboutThatShare) {
    hub.set_fault_all({FaultKind::silent, 0.25, {}});
    int answered = 0;
    for (int i = 0; i < 4000; ++i)
        answered += static_cast<int>(send("a0\r").size());
    EXPECT_GT(answered, 2700);  // 3000 expected
    EXPECT_LT(answered, 3300);
}

TEST_F(HubModelTest, LogsRequestsAndAnswers) {
    hub.clear_log();
    (void)hub.receive("a0\ra1\r", 42us);
    ASSERT_EQ(hub.log().size(), 2u);
    EXPECT_EQ(hub.log()[0].request, "a0");
    EXPECT_EQ(hub.log()[0].answer, "0000");
    EXPECT_EQ(hub.log()[0].at, 42us);
    EXPECT_EQ(hub.log()[1].answer, "");
}

TEST_F(HubModelTest, RejectsControlOnAbsentModulesAndWrongArity) {
    EXPECT_FALSE(hub.set_values({ModuleType::dim16, 5}, std::array<std::uint16_t, 1>{1}));
    EXPECT_FALSE(hub.set_values({ModuleType::dim16, 0}, std::array<std::uint16_t, 3>{1, 2, 3}));
    EXPECT_FALSE(hub.values({ModuleType::dcvim, 0}));
}

TEST_F(HubModelTest, AnOutputCanBeResetBehindTheMastersBack) {
    ASSERT_TRUE(hub.add({ModuleType::rgbdm, 0}));
    EXPECT_TRUE(hub.set_values({ModuleType::rgbdm, 0}, std::array<std::uint16_t, 1>{3}));
    EXPECT_EQ(hub.values({ModuleType::rgbdm, 0}).value(), std::vector<std::uint16_t>{3});
    EXPECT_FALSE(hub.set_values({ModuleType::rgbdm, 0}, std::array<std::uint16_t, 1>{8}));
    EXPECT_FALSE(hub.set_values({ModuleType::rgbdm, 0}, std::array<std::uint16_t, 2>{1, 2}));
}

TEST(Id2Model, AnswersEachCommandByte) {
    DeviceModel id2(Protocol::id2, 1);
    id2.set_stop_input(true);
    id2.set_counter(42);
    const auto answers = id2.receive("ICRCx", 0us);
    ASSERT_EQ(answers.size(), 4u);  // 'x' is no command: silence
    EXPECT_EQ(answers[0].bytes, "1\n");
    EXPECT_EQ(answers[1].bytes, "00042\n");
    EXPECT_EQ(answers[2].bytes, "OK\n");
    EXPECT_EQ(answers[3].bytes, "00000\n");
    id2.pulse(65535);
    id2.pulse(2);
    EXPECT_EQ(id2.counter(), 1);  // a 16-bit counter wraps
}

TEST(Id2Model, FaultedResetDoesNotClearTheCounter) {
    DeviceModel id2(Protocol::id2, 1);
    id2.set_counter(9);
    id2.set_fault_all({FaultKind::garbage, 1.0, {}});
    const auto answers = id2.receive("R", 0us);
    ASSERT_EQ(answers.size(), 1u);
    EXPECT_EQ(answers[0].bytes.back(), '\n');
    EXPECT_EQ(id2.counter(), 9);
}

}  // namespace
}  // namespace ioport::sim
