#include <gtest/gtest.h>

#include "config/duration.hpp"

namespace ioport {
namespace {

using namespace std::chrono_literals;

TEST(Duration, ParsesEveryUnit) {
    EXPECT_EQ(parse_duration("500us"), 500us);
    EXPECT_EQ(parse_duration("100ms"), 100ms);
    EXPECT_EQ(parse_duration("2s"), 2s);
    EXPECT_EQ(parse_duration("5m"), 5min);
    EXPECT_EQ(parse_duration("0"), 0us);
    EXPECT_EQ(parse_duration("0ms"), 0us);
}

TEST(Duration, RejectsWhatIsNotADuration) {
    for (const auto* text :
         {"", "100", "ms", "-1s", "1.5s", "1h", "10 ms", "1sec", "99999999999999999m"}) {
        const auto parsed = parse_duration(text);
        ASSERT_FALSE(parsed) << text;
        EXPECT_NE(parsed.error().message.find("e.g. 500us"), std::string::npos);
    }
}

TEST(Duration, FormatsTheShortestExactSpelling) {
    EXPECT_EQ(format_duration(100ms), "100ms");
    EXPECT_EQ(format_duration(2s), "2s");
    EXPECT_EQ(format_duration(5min), "5m");
    EXPECT_EQ(format_duration(1500us), "1500us");
    EXPECT_EQ(format_duration(0us), "0");
}

}  // namespace
}  // namespace ioport
