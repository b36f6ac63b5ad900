#include "daemon/options.hpp"

#include <gtest/gtest.h>

#include <vector>

namespace ioport::daemon {
namespace {

Expected<Options, std::string> parse(std::vector<std::string_view> arguments) {
    return parse_options(arguments);
}

TEST(DaemonOptions, DefaultsRunTheDefaultConfig) {
    const auto options = parse({});
    ASSERT_TRUE(options);
    EXPECT_EQ(options->mode, Options::Mode::run);
    EXPECT_EQ(options->config_path, "/etc/ioportd/ioportd.yaml");
    EXPECT_EQ(options->log_level, std::nullopt);  // the configuration's
    EXPECT_EQ(options->log_target, Options::LogTarget::automatic);
}

TEST(DaemonOptions, EveryMode) {
    EXPECT_EQ(parse({"--check-config"})->mode, Options::Mode::check_config);
    EXPECT_EQ(parse({"--print-map"})->mode, Options::Mode::print_map);
    EXPECT_EQ(parse({"--version"})->mode, Options::Mode::version);
    EXPECT_EQ(parse({"-h"})->mode, Options::Mode::help);
    const auto map = parse({"-c", "x.yaml", "--print-map", "--format", "csv"});
    ASSERT_TRUE(map);
    EXPECT_EQ(map->config_path, "x.yaml");
    EXPECT_EQ(map->map_format, Options::MapFormat::csv);
}

TEST(DaemonOptions, LoggingChoices) {
    const auto options = parse({"--log-level", "debug", "--log", "journal"});
    ASSERT_TRUE(options);
    EXPECT_EQ(options->log_level, config::LogLevel::debug);
    EXPECT_EQ(options->log_target, Options::LogTarget::journal);
    EXPECT_EQ(parse({"--log", "stderr"})->log_target, Options::LogTarget::standard_error);
    EXPECT_EQ(parse({"--log-level", "off"})->log_level, config::LogLevel::off);
    EXPECT_EQ(parse({"--log-level", "error"})->log_level, config::LogLevel::err);
}

TEST(DaemonOptions, OptionsAsPeopleTypeThem) {
    for (const auto& arguments :
         std::vector<std::vector<std::string_view>>{{"--config=x.yaml"},
                                                    {"--config", "x.yaml"},
                                                    {"-c", "x.yaml"},
                                                    {"-cx.yaml"},
                                                    {"--conf", "x.yaml"},
                                                    {"-Vcx.yaml"},
                                                    {"-V", "--config=x.yaml"}}) {
        const auto options = parse(arguments);
        ASSERT_TRUE(options) << arguments.front() << ": " << options.error();
        EXPECT_EQ(options->config_path, "x.yaml") << arguments.front();
    }
    EXPECT_EQ(parse({"-Vcx.yaml"})->mode, Options::Mode::version);
    EXPECT_EQ(parse({"-hV"})->mode, Options::Mode::version);  // the last one wins
    const auto options = parse({"--log-level=warn", "--log=stderr", "--print-map", "--format=csv"});
    ASSERT_TRUE(options) << options.error();
    EXPECT_EQ(options->log_level, config::LogLevel::warn);
    EXPECT_EQ(options->log_target, Options::LogTarget::standard_error);
    EXPECT_EQ(options->map_format, Options::MapFormat::csv);
}

// getopt_long keeps its place in globals: each parse starts afresh, also after one that stopped
// in the middle of a cluster.
TEST(DaemonOptions, EachParseStartsAfresh) {
    EXPECT_FALSE(parse({"-xV", "-c", "a.yaml"}));
    const auto options = parse({"-c", "b.yaml"});
    ASSERT_TRUE(options) << options.error();
    EXPECT_EQ(options->config_path, "b.yaml");
    EXPECT_EQ(options->mode, Options::Mode::run);
}

TEST(DaemonOptions, MistakesAreNamed) {
    EXPECT_NE(parse({"--config"}).error().find("--config needs a path"), std::string::npos);
    EXPECT_NE(parse({"--bogus"}).error().find("unknown option '--bogus'"), std::string::npos);
    EXPECT_NE(parse({"-x"}).error().find("unknown option '-x'"), std::string::npos);
    EXPECT_NE(parse({"extra"}).error().find("unknown argument 'extra'"), std::string::npos);
    EXPECT_NE(parse({"-c"}).error().find("-c needs a path"), std::string::npos);
    EXPECT_NE(parse({"--config="}).error().find("--config needs a path"), std::string::npos);
    EXPECT_NE(parse({"--version=2"}).error().find("--version takes no value"), std::string::npos);
    EXPECT_NE(parse({"--lo", "debug"}).error().find("'--lo' is ambiguous: --log-level or --log"),
              std::string::npos);
    // After "--" nothing is an option.
    EXPECT_NE(parse({"--", "--check-config"}).error().find("unknown argument '--check-config'"),
              std::string::npos);
    EXPECT_NE(parse({"--print-map", "--format", "xml"}).error().find("md or csv"),
              std::string::npos);
    EXPECT_NE(parse({"--format", "csv"}).error().find("only for --print-map"), std::string::npos);
    EXPECT_NE(parse({"--log-level", "loud"}).error().find("--log-level takes"), std::string::npos);
    EXPECT_NE(parse({"--log-level", "Off"}).error().find("--log-level takes"), std::string::npos);
    EXPECT_NE(parse({"--log-level"}).error().find("--log-level takes"), std::string::npos);
    EXPECT_NE(parse({"--log"}).error().find("--log takes auto, stderr or journal"),
              std::string::npos);
}

}  // namespace
}  // namespace ioport::daemon
