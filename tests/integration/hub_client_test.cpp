// The vendor-parity Hub client against the real simulator, including unplug and replug.
#include <gtest/gtest.h>

#include "link/hub.hpp"
#include "tests/support/process.hpp"

namespace ioport {
namespace {

using namespace std::chrono_literals;

class HubClientTest : public ::testing::Test {
  protected:
    test::SimProcess sim{"--hub",
                         "dim16:0,dom16:1,acm3p:0,acm3c:2,lim16:3,rgbdm:0,dccim:4,dcvim:5,mux8m:6"};
    Hub hub;
    // Not the vendor's 100 ms: nothing here is about time, and on a machine whose cores are busy
    // the simulator can take longer than that to answer.
    const HubOptions patient{.timeout = 1s};
    void SetUp() override { ASSERT_TRUE(hub.open(sim.link(), patient)) << hub.last_error(); }
};

TEST_F(HubClientTest, ReadsEveryInputTypeInEngineeringUnits) {
    sim.ctl("set dim16:0 0x8001");
    sim.ctl("set lim16:3 0x0004");
    sim.ctl("set acm3p:0 0 32768 65535");
    sim.ctl("set acm3c:2 13208 41203 4095");
    sim.ctl("set dccim:4 32768");
    sim.ctl("set dcvim:5 65535");
    for (const auto* module : {"dim16:0", "lim16:3", "acm3p:0", "acm3c:2", "dccim:4", "dcvim:5"})
        ASSERT_TRUE(hub.update(*parse_module_address(module)))
            << module << ": " << hub.last_error();
    EXPECT_TRUE(*hub.dim16(0, 0));
    EXPECT_FALSE(*hub.dim16(0, 1));
    EXPECT_TRUE(*hub.dim16(0, 15));
    EXPECT_TRUE(*hub.lim16(3, 2));
    EXPECT_DOUBLE_EQ(*hub.acm3p(0, 2), 100.0);
    EXPECT_NEAR(*hub.acm3p(0, 1), 50.0, 0.001);
    EXPECT_DOUBLE_EQ(*hub.acm3c(2, 0), 13208 / 65535.0 * 100);
    EXPECT_NEAR(*hub.dccim(4), 3.0, 0.001);
    EXPECT_DOUBLE_EQ(*hub.dcvim(5), 32.0);
    EXPECT_GT(hub.last_round_trip(), 0us);
}

TEST_F(HubClientTest, StagesOutputsAndSendsThemOnUpdate) {
    ASSERT_TRUE(hub.set_dom16(1, 0, true));
    ASSERT_TRUE(hub.set_dom16(1, 15, true));
    EXPECT_EQ(sim.ctl("get dom16:1"), "0\n");  // staged only
    ASSERT_TRUE(hub.update("dom16", 1)) << hub.last_error();
    EXPECT_EQ(sim.ctl("get dom16:1"), "32769\n");
    ASSERT_TRUE(hub.set_rgbdm(0, Colour::cyan));
    ASSERT_TRUE(hub.update("rgbdm", 0));
    EXPECT_EQ(sim.ctl("get rgbdm:0"), "4\n");
    ASSERT_TRUE(hub.set_mux8m(6, 7, 2));
    ASSERT_TRUE(hub.update("mux8m", 6));
    EXPECT_EQ(sim.ctl("get mux8m:6"), "1794\n");  // 0x0702
}

TEST_F(HubClientTest, ErrorsAreValuesAndGetErrExplainsThem) {
    EXPECT_FALSE(hub.dim16(0, 0));  // not read yet
    EXPECT_NE(hub.last_error().find("call update() first"), std::string::npos);
    EXPECT_FALSE(hub.update("dim17", 0));
    EXPECT_NE(hub.last_error().find("unknown module type 'dim17'"), std::string::npos);
    EXPECT_FALSE(hub.set_dom16(8, 0, true));
    EXPECT_FALSE(hub.set_mux8m(0, 8, 0));
    const auto absent = hub.update("dim16", 7);
    ASSERT_FALSE(absent);
    EXPECT_EQ(absent.error().code, Errc::timeout);
    EXPECT_NE(hub.last_error().find("dim16 7"), std::string::npos);
    sim.ctl("fault dom16:1 error-ack");
    const auto refused = hub.update("dom16", 1);
    ASSERT_FALSE(refused);
    EXPECT_EQ(refused.error().code, Errc::error_ack);
}

TEST_F(HubClientTest, SurvivesUnplugAndReopensByPath) {
    ASSERT_TRUE(hub.update("dim16", 0));
    sim.ctl("unplug");
    const auto lost = hub.update("dim16", 0);
    ASSERT_FALSE(lost);
    EXPECT_EQ(lost.error().code, Errc::port_lost) << lost.error().message;
    EXPECT_FALSE(hub.is_open());
    const auto reopen_while_out = hub.open(sim.link(), patient);
    ASSERT_FALSE(reopen_while_out);
    EXPECT_EQ(reopen_while_out.error().code, Errc::port_not_found);
    sim.ctl("replug");  // a new pty behind the same path
    sim.ctl("set dim16:0 0x0F0F");
    ASSERT_TRUE(hub.open(sim.link(), patient)) << hub.last_error();
    ASSERT_TRUE(hub.update("dim16", 0)) << hub.last_error();
    EXPECT_TRUE(*hub.dim16(0, 0));
    EXPECT_FALSE(*hub.dim16(0, 4));
}

}  // namespace
}  // namespace ioport
