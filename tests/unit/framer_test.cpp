#include <gtest/gtest.h>

#include <vector>

#include "protocol/framer.hpp"

namespace ioport {
namespace {

struct Collected {
    std::string bytes;
    bool overflowed;
    bool operator==(const Collected&) const = default;
};

std::vector<Collected> feed_all(LineFramer& framer,
                                std::initializer_list<std::string_view> chunks) {
    std::vector<Collected> frames;
    for (const auto chunk : chunks)
        framer.feed(chunk, [&](const Frame& f) {
            frames.push_back({std::string(f.bytes), f.overflowed});
        });
    return frames;
}

TEST(LineFramer, JoinsFramesSplitAcrossReads) {
    LineFramer framer('\r', 12);
    EXPECT_EQ(feed_all(framer, {"33", "98A0F3", "0FFF", "\r"}),
              (std::vector<Collected>{{"3398A0F30FFF", false}}));
    EXPECT_FALSE(framer.partial());
}

TEST(LineFramer, YieldsEveryFrameOfOneRead) {
    LineFramer framer('\r', 4);
    EXPECT_EQ(
        feed_all(framer, {"0000\r8000\r1\r\r"}),
        (std::vector<Collected>{{"0000", false}, {"8000", false}, {"1", false}, {"", false}}));
}

TEST(LineFramer, OverlongLineIsFlaggedAndResynchronisesOnTheNextTerminator) {
    LineFramer framer('\r', 4);
    const auto frames = feed_all(framer, {"FFFFFFFFFF", "FFFF\rABCD\r"});
    ASSERT_EQ(frames.size(), 2u);
    EXPECT_TRUE(frames[0].overflowed);
    EXPECT_EQ(frames[0].bytes, "FFFF");
    EXPECT_EQ(frames[1], (Collected{"ABCD", false}));
}

TEST(LineFramer, KeepsAPartialLineUntilReset) {
    LineFramer framer('\n', 5);
    EXPECT_TRUE(feed_all(framer, {"000"}).empty());
    EXPECT_TRUE(framer.partial());
    framer.reset();
    EXPECT_EQ(feed_all(framer, {"OK\n"}), (std::vector<Collected>{{"OK", false}}));
}

}  // namespace
}  // namespace ioport
