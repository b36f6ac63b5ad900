#include <gtest/gtest.h>

#include "protocol/reply_window.hpp"

namespace ioport {
namespace {

using State = ReplyWindow::State;

TEST(ReplyWindow, OneFrameAloneIsComplete) {
    ReplyWindow window('\r', 4);
    EXPECT_EQ(window.feed("40"), State::waiting);
    EXPECT_EQ(window.frame(), "");
    EXPECT_EQ(window.feed("0C\r"), State::complete);
    EXPECT_EQ(window.frame(), "400C");
}

// A device that buffered requests answers them in order when it resumes: the first frame is the
// oldest owed answer (dim16 1's "400C" while dccim 0 waits), the request's own comes after it.
TEST(ReplyWindow, AnythingAfterTheFirstFrameInTheSameReadMakesItExtra) {
    ReplyWindow window('\r', 4);
    EXPECT_EQ(window.feed("400C\r1234\r"), State::extra);
    EXPECT_EQ(window.frame(), "400C");
    EXPECT_EQ(window.extra(), "1234\r");
}

TEST(ReplyWindow, AnythingAfterTheFirstFrameInALaterReadMakesItExtra) {
    ReplyWindow window('\r', 1);
    EXPECT_EQ(window.feed("1\r"), State::complete);  // a stale acknowledgement of another write
    EXPECT_EQ(window.feed("0"), State::extra);       // this write's own answer, an error
    EXPECT_EQ(window.feed("\r"), State::extra);      // final
    EXPECT_EQ(window.frame(), "1");
}

TEST(ReplyWindow, ABareTerminatorAfterTheFrameIsExtraToo) {
    ReplyWindow window('\n', 5);
    EXPECT_EQ(window.feed("00042\n\n"), State::extra);
}

TEST(ReplyWindow, AnOverlongFirstFrameIsOverflowedAndFinal) {
    ReplyWindow window('\r', 4);
    EXPECT_EQ(window.feed("3398A0F30FFF"), State::waiting);
    EXPECT_EQ(window.feed("\r"), State::overflowed);
    EXPECT_EQ(window.frame(), "3398");
    EXPECT_EQ(window.feed("1234\r"), State::overflowed);
}

TEST(ReplyWindow, AShortFrameIsCompleteForTheDecoderToReject) {
    ReplyWindow window('\r', 12);
    EXPECT_EQ(window.feed("1\r"), State::complete);
    EXPECT_EQ(window.frame(), "1");
}

TEST(ReplyWindow, ByteByByte) {
    ReplyWindow window('\r', 12);
    for (const char c : std::string_view("3398A0F30FFF"))
        EXPECT_EQ(window.feed({&c, 1}), State::waiting);
    EXPECT_EQ(window.feed("\r"), State::complete);
    EXPECT_EQ(window.frame(), "3398A0F30FFF");
}

}  // namespace
}  // namespace ioport
