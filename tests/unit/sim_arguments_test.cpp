// ioport-sim's command line: options as people type them, and mistakes named.
#include <gtest/gtest.h>

#include <sstream>
#include <vector>

#include "tools/sim_cli.hpp"

namespace ioport::sim_cli {
namespace {

using namespace std::chrono_literals;

Result<Invocation> parse(std::vector<std::string_view> args) {
    return parse_arguments(args);
}

TEST(SimArguments, EveryOption) {
    const auto invocation =
        parse({"--link", "/tmp/tty", "--hub", "dim16:0,dom16:0-1", "--control", "/tmp/ctl",
               "--baud", "38400", "--turnaround", "1ms", "--no-line-timing", "--seed", "7"});
    ASSERT_TRUE(invocation) << invocation.error().message;
    const auto& serve = std::get<Serve>(*invocation);
    EXPECT_EQ(serve.settings.link_path, "/tmp/tty");
    EXPECT_EQ(serve.settings.control_path, "/tmp/ctl");
    EXPECT_EQ(serve.settings.baud, 38400);
    EXPECT_EQ(serve.settings.turnaround, 1ms);
    EXPECT_FALSE(serve.settings.line_timing);
    EXPECT_EQ(serve.seed, 7U);
    EXPECT_EQ(serve.protocol, sim::Protocol::ioport);
    EXPECT_EQ(serve.modules,
              (std::vector<ModuleAddress>{
                  {ModuleType::dim16, 0}, {ModuleType::dom16, 0}, {ModuleType::dom16, 1}}));
}

TEST(SimArguments, Wander) {
    const auto invocation = parse(
        {"--link", "/x", "--hub", "dim16:0-1,acm3p:0", "--wander", "20ms", "--still", "dim16:0"});
    ASSERT_TRUE(invocation) << invocation.error().message;
    const auto& serve = std::get<Serve>(*invocation);
    EXPECT_EQ(serve.wander, 20ms);
    EXPECT_EQ(serve.still, (std::vector<ModuleAddress>{{ModuleType::dim16, 0}}));
    EXPECT_EQ(std::get<Serve>(*parse({"--link", "/x", "--id2"})).wander, 0ms);  // default: off
}

TEST(SimArguments, ValuesAfterAnEqualsSign) {
    const auto invocation = parse({"--link=/tmp/tty", "--id2", "--seed=3", "--baud=9600"});
    ASSERT_TRUE(invocation) << invocation.error().message;
    const auto& serve = std::get<Serve>(*invocation);
    EXPECT_EQ(serve.settings.link_path, "/tmp/tty");
    EXPECT_EQ(serve.protocol, sim::Protocol::id2);
    EXPECT_EQ(serve.seed, 3U);
    EXPECT_EQ(serve.settings.baud, 9600);
    EXPECT_EQ(std::get<Serve>(*parse({"--id2", "--link=/x"})).settings.baud, 9600);  // default
}

TEST(SimArguments, HelpAndControl) {
    EXPECT_TRUE(std::holds_alternative<Help>(*parse({"-h"})));
    EXPECT_TRUE(std::holds_alternative<Help>(*parse({"--link", "/x", "--help"})));
    // The control command's words are passed on as they are, dashes too.
    const auto control = parse({"ctl", "/tmp/ctl", "set", "dom16:0", "-1", "--now"});
    ASSERT_TRUE(control) << control.error().message;
    EXPECT_EQ(std::get<Control>(*control).socket, "/tmp/ctl");
    EXPECT_EQ(std::get<Control>(*control).command, "set dom16:0 -1 --now");
}

TEST(SimArguments, MistakesAreNamed) {
    const std::vector<std::pair<std::vector<std::string_view>, std::string_view>> cases{
        {{"--id2", "--link"}, "--link needs a value"},
        {{"--id2", "--link", "/x", "--bogus"}, "unknown option '--bogus'"},
        {{"--id2", "--link", "/x", "-x"}, "unknown option '-x'"},
        {{"--id2", "--link", "/x", "extra"}, "unknown argument 'extra'"},
        {{"--id2=1", "--link", "/x"}, "--id2 takes no value"},
        {{"--id2"}, "--link PATH is required"},
        {{"--link", "/x"}, "give either --hub MODULES or --id2"},
        {{"--link", "/x", "--id2", "--hub", "dim16:0"}, "give either --hub MODULES or --id2"},
        {{"--link", "/x", "--hub", "dim16:3-1"}, "a range is TYPE:N-M"},
        {{"--link", "/x", "--id2", "--baud", "1200"}, "9600, 38400 or 115200"},
        {{"--link", "/x", "--id2", "--seed", "x"}, "seed 'x': a whole number"},
        {{"--link", "/x", "--id2", "--wander", "0ms"}, "wander '0ms': a period"},
        {{"ctl", "/tmp/ctl"}, "ctl takes SOCKET COMMAND"},
    };
    for (const auto& [args, message] : cases) {
        const auto invocation = parse_arguments(args);
        ASSERT_FALSE(invocation) << message;
        EXPECT_EQ(invocation.error().code, Errc::invalid_argument);
        EXPECT_NE(invocation.error().message.find(message), std::string::npos)
            << invocation.error().message;
    }
}

TEST(SimArguments, UsageErrorsExitWithTwo) {
    std::ostringstream out, err;
    const std::vector<std::string_view> args{"--bogus"};
    EXPECT_EQ(run_command_line(args, out, err), 2);
    EXPECT_TRUE(err.str().starts_with("ioport-sim: unknown option '--bogus'")) << err.str();
    EXPECT_TRUE(out.str().empty());
}

}  // namespace
}  // namespace ioport::sim_cli
