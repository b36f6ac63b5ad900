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
}

TEST(DaemonOptions, MistakesAreNamed) {
    EXPECT_NE(parse({"--config"}).error().find("--config needs a path"), std::string::npos);
    EXPECT_NE(parse({"--bogus"}).error().find("unknown argument '--bogus'"), std::string::npos);
    EXPECT_NE(parse({"--print-map", "--format", "xml"}).error().find("md or csv"),
              std::string::npos);
    EXPECT_NE(parse({"--format", "csv"}).error().find("only for --print-map"), std::string::npos);
    EXPECT_NE(parse({"--log-level", "loud"}).error().find("--log-level takes"), std::string::npos);
    EXPECT_NE(parse({"--log"}).error().find("--log takes auto, stderr or journal"),
              std::string::npos);
}

}  // namespace
}  // namespace ioport::daemon
