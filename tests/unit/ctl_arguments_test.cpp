// ioportctl's command line: every command parses to what it says, and bad input is a usage error.
#include <gtest/gtest.h>

#include <sstream>

#include "tools/ctl.hpp"

namespace ioport::ctl {
namespace {

using namespace std::chrono_literals;

Result<Invocation> parse(std::initializer_list<std::string_view> args) {
    const std::vector<std::string_view> list(args);
    return parse_arguments(list, "/dev/ttyUSB0");
}

TEST(CtlArguments, ReadWithOptionsAnywhere) {
    const auto inv = parse(
        {"read", "acm3p:1", "--json", "-p", "/dev/x", "-t", "50ms", "-r", "2", "-b", "38400"});
    ASSERT_TRUE(inv) << inv.error().message;
    EXPECT_EQ(std::get<Read>(inv->command).module, (ModuleAddress{ModuleType::acm3p, 1}));
    EXPECT_EQ(inv->options.port, "/dev/x");
    EXPECT_EQ(inv->options.timeout, 50ms);
    EXPECT_EQ(inv->options.retries, 2);
    EXPECT_EQ(inv->options.baud, 38400);
    EXPECT_TRUE(inv->options.json);
}

TEST(CtlArguments, OptionsAsPeopleTypeThem) {
    for (const auto& args : std::vector<std::vector<std::string_view>>{
             {"--port=/dev/x", "--timeout=50ms", "--retries=2", "--baud=38400", "read", "dim16:0"},
             {"-p/dev/x", "-t50ms", "-r2", "-b38400", "read", "dim16:0"},
             {"read", "-p", "/dev/x", "dim16:0", "--time", "50ms", "--ret", "2", "-b", "38400"},
             {"-r", "2", "-p/dev/x", "read", "--baud", "38400", "--timeout", "50ms", "--",
              "dim16:0"}}) {
        const auto inv = parse_arguments(args, "/dev/ttyUSB0");
        ASSERT_TRUE(inv) << args.front() << ": " << inv.error().message;
        EXPECT_EQ(std::get<Read>(inv->command).module, (ModuleAddress{ModuleType::dim16, 0}));
        EXPECT_EQ(inv->options.port, "/dev/x");
        EXPECT_EQ(inv->options.timeout, 50ms);
        EXPECT_EQ(inv->options.retries, 2);
        EXPECT_EQ(inv->options.baud, 38400);
    }
    EXPECT_TRUE(std::holds_alternative<Version>(parse({"-Vh"})->command));
    EXPECT_TRUE(std::holds_alternative<Help>(parse({"-hV"})->command));
}

// getopt_long keeps its place in globals: each parse starts afresh, also after one that stopped
// in the middle of a cluster.
TEST(CtlArguments, EachParseStartsAfresh) {
    EXPECT_FALSE(parse({"-xV", "read", "dim16:0"}));
    const auto inv = parse({"read", "dim16:1"});
    ASSERT_TRUE(inv) << inv.error().message;
    EXPECT_EQ(std::get<Read>(inv->command).module, (ModuleAddress{ModuleType::dim16, 1}));
}

TEST(CtlArguments, WriteWordInEveryBase) {
    for (const auto* word : {"0x93D1", "37841", "0b1001001111010001"}) {
        const auto inv = parse({"write", "dom16:0", word});
        ASSERT_TRUE(inv) << word;
        EXPECT_EQ(std::get<Write>(inv->command).value, 0x93D1);
    }
}

TEST(CtlArguments, WriteSingleOutput) {
    const auto on = parse({"write", "dom16:2", "15", "on"});
    ASSERT_TRUE(on);
    EXPECT_EQ(std::get<Write>(on->command).value, 0x8000);
    EXPECT_EQ(std::get<Write>(on->command).single_output, 15);
    EXPECT_EQ(std::get<Write>(parse({"write", "dom16:2", "3", "off"})->command).value, 0);
}

TEST(CtlArguments, RgbMuxId2Scan) {
    EXPECT_EQ(std::get<Write>(parse({"rgb", "2", "magenta"})->command).value, 5);
    EXPECT_EQ(std::get<Write>(parse({"rgb", "2", "7"})->command).value, 7);
    EXPECT_EQ(std::get<Write>(parse({"mux", "3", "0", "5"})->command).value, 0x0005);
    EXPECT_EQ(std::get<Write>(parse({"mux", "3", "off"})->command).value, 0);
    EXPECT_EQ(std::get<Id2>(parse({"id2", "count"})->command).command, id2::Command::count);
    EXPECT_TRUE(std::holds_alternative<Scan>(parse({"scan", "--inputs-only"})->command));
    EXPECT_TRUE(std::holds_alternative<Help>(parse({"read", "--help"})->command));
    EXPECT_TRUE(std::holds_alternative<Version>(parse({"-V"})->command));
}

// A scan leaves output modules alone unless it is told to switch them off.
TEST(CtlArguments, ScanResetsOutputsOnlyWhenAsked) {
    const auto plain = parse({"scan"});
    ASSERT_TRUE(plain) << plain.error().message;
    EXPECT_TRUE(std::holds_alternative<Scan>(plain->command));
    EXPECT_FALSE(plain->options.reset_outputs);
    const auto reset = parse({"scan", "--reset-outputs"});
    ASSERT_TRUE(reset) << reset.error().message;
    EXPECT_TRUE(reset->options.reset_outputs);
    EXPECT_FALSE(parse({"scan", "--inputs-only"})->options.reset_outputs);
}

TEST(CtlArguments, BadInputIsAUsageErrorThatSaysWhatIsAllowed) {
    // Vectors, not initializer_lists: those would not outlive the table's own initialisation.
    const std::vector<std::pair<std::vector<std::string_view>, std::string_view>> cases{
        {{}, "no command"},
        {{"read"}, "read takes one MODULE"},
        {{"read", "dom16:0"}, "is not an input module"},
        {{"read", "dim16:8"}, "NUMBER 0-7"},
        {{"write", "dom16:0", "0x10000"}, "not a 16-bit word"},
        {{"write", "rgbdm:0", "1"}, "is not a dom16"},
        {{"write", "dom16:0", "16", "on"}, "use 0-15"},
        {{"write", "dom16:0", "1", "maybe"}, "say on or off"},
        {{"rgb", "0", "purple"}, "is not a colour"},
        {{"rgb", "8", "red"}, "module number"},
        {{"mux", "0", "8", "1"}, "each must be 0-7"},
        {{"id2", "jump"}, "stop, count or reset"},
        {{"scan", "extra"}, "takes no arguments"},
        {{"read", "dim16:0", "--inputs-only"}, "goes with scan"},
        {{"write", "dom16:0", "1", "--reset-outputs"}, "--reset-outputs goes with scan"},
        {{"scan", "--reset-outputs", "--inputs-only"}, "contradict each other"},
        {{"read", "dim16:0", "-t", "0ms"}, "from 1ms to 10s"},
        {{"read", "dim16:0", "-b", "9601"}, "use 115200 or 38400"},
        {{"read", "dim16:0", "-r", "x"}, "use 0-10"},
        {{"read", "dim16:0", "-p"}, "-p needs a value"},
        {{"read", "dim16:0", "--port"}, "--port needs a value"},
        {{"read", "dim16:0", "--frobnicate"}, "unknown option '--frobnicate'"},
        {{"read", "dim16:0", "-x"}, "unknown option '-x'"},
        {{"read", "dim16:0", "--json=yes"}, "--json takes no value"},
        {{"read", "dim16:0", "--", "--json"}, "read takes one MODULE"},
        {{"launch"}, "unknown command"},
    };
    for (const auto& [args, message] : cases) {
        const auto inv = parse_arguments(args, "/dev/ttyUSB0");
        ASSERT_FALSE(inv) << message;
        EXPECT_EQ(inv.error().code, Errc::invalid_argument);
        EXPECT_NE(inv.error().message.find(message), std::string::npos) << inv.error().message;
    }
}

TEST(CtlArguments, MainReportsUsageErrorsWithExitTwo) {
    std::ostringstream out, err;
    const std::vector<std::string_view> args{"read"};
    EXPECT_EQ(run_command_line(args, "/dev/null", out, err), exit_usage);
    EXPECT_TRUE(err.str().starts_with("ioportctl: read takes one MODULE"));
    EXPECT_TRUE(out.str().empty());
}

TEST(CtlArguments, HelpListsEveryCommandAndExitStatus) {
    std::ostringstream out, err;
    const std::vector<std::string_view> args{"--help"};
    EXPECT_EQ(run_command_line(args, "/dev/null", out, err), exit_ok);
    for (const auto* word : {"read MODULE", "write dom16:N WORD", "rgb N COLOUR", "mux N POS NEG",
                             "id2 stop|count|reset", "scan", "Exit status"})
        EXPECT_NE(out.str().find(word), std::string::npos) << word;
}

}  // namespace
}  // namespace ioport::ctl
