// The real ioportctl binary against the real ioport-sim on a pty: every command, every fault.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "tests/support/beside_program.hpp"
#include "tests/support/process.hpp"
#include "tests/support/timing.hpp"

namespace ioport {
namespace {

using namespace std::chrono_literals;
using test::Outcome;

// A scan's deadline for each address's answer: the simulator is as slow as the build (under the
// sanitizers, beside other tests, a 20 ms scan missed a module that was there).
// A scan's timeout: what an absent address costs. Natively not a hub's 20 ms: a simulator
// starved of CPU on a busy machine answers later (beside two busy loops it missed 50 ms). Under
// the sanitizers and emulation 20 ms a unit of slowdown, as before, which covered that already:
// 100 ms times the slowdown made the scans of the arm64 stage take 2 minutes more.
std::string scan_timeout() {
    return std::to_string(std::max(100, 20 * test::slowdown)) + "ms";
}

class IoportctlTest : public ::testing::Test {
  protected:
    test::SimProcess sim{"--hub",
                         "dim16:0,dom16:0,acm3p:1,acm3c:0,lim16:2,rgbdm:3,dccim:0,dcvim:7,mux8m:0"};
    Outcome ctl(std::vector<std::string> args) {
        std::vector<std::string> argv{IOPORTCTL_BINARY, "-p", sim.link()};
        argv.insert(argv.end(), args.begin(), args.end());
        return test::run(argv);
    }
};

// The requests the simulator received since the last "log clear", one per line of its log
// ("<µs> <request> <answer>").
std::vector<std::string> requests(test::SimProcess& sim) {
    std::istringstream log(sim.ctl("log"));
    std::vector<std::string> sent;
    std::string at, request, answer;
    while (log >> at >> request >> answer)
        if (at != "ok") sent.push_back(request);
    return sent;
}

bool any_to_outputs(const std::vector<std::string>& sent) {
    return std::ranges::any_of(sent, [](const std::string& request) {
        return request.starts_with('b') || request.starts_with('f') || request.starts_with('i');
    });
}

TEST_F(IoportctlTest, ScanWithResetOutputsListsExactlyTheModulesOnTheHub) {
    const auto scan = ctl({"scan", "--timeout", scan_timeout(), "--reset-outputs"});
    ASSERT_EQ(scan.exit_code, 0) << scan.err;
    EXPECT_NE(scan.out.find("9 module(s) answered"), std::string::npos) << scan.out;
    EXPECT_NE(scan.out.find("72 addresses probed"), std::string::npos);
    const auto json = ctl({"scan", "--timeout", scan_timeout(), "--json", "--reset-outputs"});
    ASSERT_EQ(json.exit_code, 0) << json.err;
    EXPECT_NE(json.out.find(R"("probed":72,"outputs_probed":true)"), std::string::npos) << json.out;
    std::string found;
    for (std::size_t at = 0; (at = json.out.find(R"("module":")", at)) != std::string::npos;) {
        at += 10;
        found +=
            json.out.substr(at, 5) + ":" + json.out[json.out.find(R"("number":)", at) + 9] + ",";
    }
    EXPECT_EQ(found, "dim16:0,dom16:0,acm3p:1,acm3c:0,lim16:2,rgbdm:3,dccim:0,dcvim:7,mux8m:0,");
}

// A scan must not change a running plant: by default it sends the output modules nothing, and
// says so.
TEST_F(IoportctlTest, ScanLeavesOutputsAsTheyAre) {
    ASSERT_EQ(ctl({"write", "dom16:0", "0x93D1"}).exit_code, 0);
    ASSERT_EQ(ctl({"rgb", "3", "green"}).exit_code, 0);
    ASSERT_EQ(ctl({"mux", "0", "1", "5"}).exit_code, 0);
    sim.ctl("log clear");
    const auto scan = ctl({"scan", "--timeout", scan_timeout()});
    ASSERT_EQ(scan.exit_code, 0) << scan.err;
    EXPECT_NE(scan.out.find("6 module(s) answered"), std::string::npos) << scan.out;
    EXPECT_NE(scan.out.find("48 addresses probed"), std::string::npos) << scan.out;
    EXPECT_NE(scan.out.find("were not probed"), std::string::npos) << scan.out;
    EXPECT_NE(scan.out.find("ioportctl scan --reset-outputs"), std::string::npos) << scan.out;
    EXPECT_EQ(sim.ctl("get dom16:0"), "37841\n");
    EXPECT_EQ(sim.ctl("get rgbdm:3"), "2\n");
    EXPECT_EQ(sim.ctl("get mux8m:0"), "261\n");  // (1 << 8) | 5
    const auto sent = requests(sim);
    EXPECT_EQ(sent.size(), 48U);
    EXPECT_FALSE(any_to_outputs(sent)) << scan.out;
    const auto json = ctl({"scan", "--timeout", scan_timeout(), "--json"});
    ASSERT_EQ(json.exit_code, 0) << json.err;
    EXPECT_NE(json.out.find(R"("probed":48,"outputs_probed":false)"), std::string::npos)
        << json.out;
    EXPECT_EQ(sim.ctl("get dom16:0"), "37841\n");
}

TEST_F(IoportctlTest, ScanResetOutputsSwitchesThemOff) {
    ASSERT_EQ(ctl({"write", "dom16:0", "0x93D1"}).exit_code, 0);
    ASSERT_EQ(ctl({"rgb", "3", "green"}).exit_code, 0);
    ASSERT_EQ(ctl({"mux", "0", "1", "5"}).exit_code, 0);
    const auto scan = ctl({"scan", "--timeout", scan_timeout(), "--reset-outputs"});
    ASSERT_EQ(scan.exit_code, 0) << scan.err;
    EXPECT_NE(scan.out.find("9 module(s) answered"), std::string::npos) << scan.out;
    EXPECT_NE(scan.out.find("are now off"), std::string::npos) << scan.out;
    EXPECT_EQ(sim.ctl("get dom16:0"), "0\n");
    EXPECT_EQ(sim.ctl("get rgbdm:3"), "0\n");
    EXPECT_EQ(sim.ctl("get mux8m:0"), "0\n");
}

TEST_F(IoportctlTest, ScanInputsOnlySendsNothingToOutputs) {
    ASSERT_EQ(ctl({"write", "dom16:0", "0x93D1"}).exit_code, 0);
    sim.ctl("log clear");
    const auto scan = ctl({"scan", "--timeout", scan_timeout(), "--inputs-only"});
    ASSERT_EQ(scan.exit_code, 0) << scan.err;
    EXPECT_NE(scan.out.find("6 module(s) answered"), std::string::npos) << scan.out;
    const auto sent = requests(sim);
    EXPECT_EQ(sent.size(), 48U);
    EXPECT_FALSE(any_to_outputs(sent));
    EXPECT_EQ(sim.ctl("get dom16:0"), "37841\n");
}

TEST_F(IoportctlTest, ReadsEveryInputModuleType) {
    sim.ctl("set dim16:0 0x8001");
    sim.ctl("set lim16:2 0x0010");
    sim.ctl("set acm3p:1 13208 41203 4095");
    sim.ctl("set acm3c:0 0 32768 65535");
    sim.ctl("set dccim:0 32768");
    sim.ctl("set dcvim:7 65535");
    EXPECT_EQ(ctl({"read", "dim16:0"}).out, "dim16 0  0x8001  on: i0 i15\n");
    EXPECT_EQ(ctl({"read", "lim16:2"}).out, "lim16 2  0x0010  on: i4\n");
    EXPECT_EQ(ctl({"read", "acm3p:1"}).out,
              "acm3p 1\n  c0  13208   20.15 %\n  c1  41203   62.87 %\n  c2   4095    6.25 %\n");
    EXPECT_EQ(ctl({"read", "acm3c:0"}).out,
              "acm3c 0\n  c0      0    0.00 %\n  c1  32768   50.00 %\n  c2  65535  100.00 %\n");
    EXPECT_EQ(ctl({"read", "dccim:0"}).out, "dccim 0  32768  3.000 A\n");
    EXPECT_EQ(ctl({"read", "dcvim:7"}).out, "dcvim 7  65535  32.000 V\n");
    const auto json = ctl({"read", "dim16:0", "--json"});
    EXPECT_EQ(json.exit_code, 0);
    EXPECT_TRUE(
        json.out.starts_with(R"({"module":"dim16","number":0,"raw":[32769],"inputs":[true,false)"))
        << json.out;
    EXPECT_NE(ctl({"read", "dcvim:7", "--json"}).out.find(R"("values":[32],"unit":"V")"),
              std::string::npos);
}

TEST_F(IoportctlTest, WritesEveryOutputModuleType) {
    EXPECT_EQ(ctl({"write", "dom16:0", "0x93D1"}).out,
              "dom16 0: outputs 0x93D1 (on: o0 o4 o6 o7 o8 o9 o12 o15)\n");
    EXPECT_EQ(sim.ctl("get dom16:0"), "37841\n");
    const auto single = ctl({"write", "dom16:0", "3", "on"});
    EXPECT_EQ(single.exit_code, 0);
    EXPECT_NE(single.err.find("other outputs of dom16 0 are now off"), std::string::npos);
    EXPECT_EQ(sim.ctl("get dom16:0"), "8\n");
    for (const auto& [colour, code] :
         std::vector<std::pair<std::string, std::string>>{{"red", "1"},
                                                          {"green", "2"},
                                                          {"blue", "3"},
                                                          {"cyan", "4"},
                                                          {"magenta", "5"},
                                                          {"yellow", "6"},
                                                          {"white", "7"},
                                                          {"off", "0"}}) {
        ASSERT_EQ(ctl({"rgb", "3", colour}).exit_code, 0) << colour;
        EXPECT_EQ(sim.ctl("get rgbdm:3"), code + "\n") << colour;
    }
    EXPECT_EQ(ctl({"mux", "0", "0", "5"}).out, "mux8m 0: tp0 on dev+, tp5 on dev-\n");
    EXPECT_EQ(sim.ctl("get mux8m:0"), "5\n");
    EXPECT_EQ(ctl({"mux", "0", "off"}).out, "mux8m 0: all test points disconnected\n");
    EXPECT_EQ(sim.ctl("get mux8m:0"), "0\n");
    EXPECT_NE(ctl({"write", "dom16:0", "0xFFFF", "--json"}).out.find(R"("value":65535,"ack":true)"),
              std::string::npos);
}

TEST_F(IoportctlTest, FaultsGiveTheDocumentedErrors) {
    struct Case {
        std::string fault;
        std::vector<std::string> args;
        int exit_code;
        std::string message;
    };
    const std::vector<Case> cases{
        {"fault dim16:0 silent",
         {"read", "dim16:0", "-t", "30ms"},
         5,
         "did not answer within 30 ms"},
        {"fault dim16:0 garbage", {"read", "dim16:0"}, 1, "dim16 0 on "},
        {"fault dim16:0 short", {"read", "dim16:0"}, 1, "(3 characters), expected 4 hex digits"},
        {"fault dim16:0 long", {"read", "dim16:0"}, 1, "is too long: expected 4 character(s)"},
        {"fault dim16:0 error-ack", {"read", "dim16:0"}, 1, "expected 4 hex digits"},
        {"fault dim16:0 delay 200ms",
         {"read", "dim16:0", "-t", "50ms", "-r", "0"},
         5,
         "did not answer"},
        {"fault dom16:0 error-ack", {"write", "dom16:0", "1"}, 1, "dom16 answered 0 (error)"},
        {"fault dom16:0 silent", {"write", "dom16:0", "1", "-t", "30ms"}, 5, "dom16 0"},
        {"fault rgbdm:3 error-ack", {"rgb", "3", "red"}, 1, "rgbdm answered 0 (error)"},
        {"fault mux8m:0 garbage", {"mux", "0", "1", "2"}, 1, "mux8m 0 on "},
    };
    for (const auto& c : cases) {
        sim.ctl("fault all none");
        sim.ctl(c.fault);
        const auto outcome = ctl(c.args);
        EXPECT_EQ(outcome.exit_code, c.exit_code) << c.fault << ": " << outcome.err;
        EXPECT_NE(outcome.err.find(c.message), std::string::npos) << c.fault << ": " << outcome.err;
        EXPECT_TRUE(outcome.out.empty()) << c.fault;
    }
    // A small delay within the timeout is fine.
    sim.ctl("fault all none");
    sim.ctl("fault dim16:0 delay 20ms");
    EXPECT_EQ(ctl({"read", "dim16:0", "-t", "200ms"}).exit_code, 0);
    // A failed write never changed the output.
    EXPECT_EQ(sim.ctl("get dom16:0"), "0\n");
}

TEST_F(IoportctlTest, RetriesRecoverFromOccasionalNoise) {
    sim.ctl("fault dim16:0 garbage 0.5");
    int ok = 0;
    for (int i = 0; i < 10; ++i)
        ok += ctl({"read", "dim16:0", "-r", "5", "-t", "30ms"}).exit_code == 0;
    EXPECT_EQ(ok, 10);
}

TEST_F(IoportctlTest, UnplugAndReplug) {
    sim.ctl("unplug");
    const auto gone = ctl({"read", "dim16:0"});
    EXPECT_EQ(gone.exit_code, 3);
    EXPECT_NE(gone.err.find("does not exist"), std::string::npos) << gone.err;
    sim.ctl("replug");
    EXPECT_EQ(ctl({"read", "dim16:0"}).exit_code, 0);
    sim.ctl("unplug 100ms");  // back by itself
    const auto deadline = std::chrono::steady_clock::now() + 5s;
    while (!std::filesystem::exists(sim.link()) && std::chrono::steady_clock::now() < deadline)
        (void)sim.ctl("modules");  // a round trip to the simulator, not a sleep
    EXPECT_EQ(ctl({"read", "dim16:0"}).exit_code, 0);
}

TEST_F(IoportctlTest, PortErrorsAndUsageErrors) {
    const auto missing =
        test::run({IOPORTCTL_BINARY, "-p", "/dev/serial/by-id/nothing-here", "read", "dim16:0"});
    EXPECT_EQ(missing.exit_code, 3);
    EXPECT_NE(missing.err.find("/dev/serial/by-id/nothing-here does not exist"), std::string::npos);
    const auto usage = ctl({"read", "dim16:9"});
    EXPECT_EQ(usage.exit_code, 2);
    EXPECT_NE(usage.err.find("NUMBER 0-7"), std::string::npos);
    const auto version = ctl({"--version"});
    EXPECT_EQ(version.exit_code, 0);
    EXPECT_TRUE(version.out.starts_with("ioportctl "));
}

TEST_F(IoportctlTest, PermissionDeniedNamesTheDialoutGroup) {
    if (::geteuid() != 0 || !std::filesystem::exists("/usr/bin/setpriv"))
        GTEST_SKIP() << "needs root and setpriv to run ioportctl as an unprivileged user";
    const auto pts = std::filesystem::read_symlink(sim.link()).string();
    ::chmod(pts.c_str(), 0600);
    const auto denied =
        test::run({"/usr/bin/setpriv", "--reuid=65534", "--regid=65534", "--clear-groups",
                   IOPORTCTL_BINARY, "-p", pts, "read", "dim16:0"});
    EXPECT_EQ(denied.exit_code, 4) << denied.err;
    EXPECT_NE(denied.err.find("add this user to the dialout group"), std::string::npos)
        << denied.err;
}

TEST(IoportctlId2, StopCountReset) {
    test::SimProcess sim{"--id2", ""};
    const auto ctl = [&](std::vector<std::string> args) {
        std::vector<std::string> argv{IOPORTCTL_BINARY, "-p", sim.link()};
        argv.insert(argv.end(), args.begin(), args.end());
        return test::run(argv);
    };
    sim.ctl("set stop 1");
    sim.ctl("set count 42");
    EXPECT_EQ(ctl({"id2", "stop"}).out, "ID-2 stop input: 1 (high)\n");
    EXPECT_EQ(ctl({"id2", "count"}).out, "ID-2 counter: 42\n");
    EXPECT_NE(ctl({"id2", "count", "--json"}).out.find(R"({"count":42,)"), std::string::npos);
    EXPECT_EQ(ctl({"id2", "reset"}).out, "ID-2 counter reset\n");
    EXPECT_EQ(sim.ctl("get count"), "0\n");
    sim.ctl("fault device silent");
    const auto silent = ctl({"id2", "count", "-t", "30ms"});
    EXPECT_EQ(silent.exit_code, 5);
    EXPECT_NE(silent.err.find("ID-2 counter on "), std::string::npos) << silent.err;
    sim.ctl("fault device garbage");
    EXPECT_EQ(ctl({"id2", "stop"}).exit_code, 1);
}

}  // namespace
}  // namespace ioport
