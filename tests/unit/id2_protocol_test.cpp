// The ID-2 wire format: one-character requests, LF-terminated replies.
#include <gtest/gtest.h>

#include "protocol/exchange.hpp"
#include "protocol/id2.hpp"

namespace ioport::id2 {
namespace {

TEST(Id2, RequestsAreOneCharacterWithoutTerminator) {
    EXPECT_EQ(encode_request(Command::stop_input), "I");
    EXPECT_EQ(encode_request(Command::count), "C");
    EXPECT_EQ(encode_request(Command::reset), "R");
}

TEST(Id2, StopInput) {
    EXPECT_EQ(parse_reply(Command::stop_input, "0"), 0);
    EXPECT_EQ(parse_reply(Command::stop_input, "1"), 1);
    for (const auto* frame : {"", "2", "01", "OK", "00042"})
        EXPECT_EQ(parse_reply(Command::stop_input, frame).error().code, Errc::malformed) << frame;
}

TEST(Id2, CounterIsFiveDecimalDigitsUpTo65535) {
    EXPECT_EQ(parse_reply(Command::count, "00042"), 42);
    EXPECT_EQ(parse_reply(Command::count, "00000"), 0);
    EXPECT_EQ(parse_reply(Command::count, "65535"), 65535);
    for (const auto* frame : {"65536", "99999", "0042", "000042", "0004a", " 0042", "-0042", ""})
        EXPECT_EQ(parse_reply(Command::count, frame).error().code, Errc::malformed) << frame;
}

TEST(Id2, ResetAnswersOk) {
    EXPECT_EQ(parse_reply(Command::reset, "OK"), 0);
    for (const auto* frame : {"ok", "O", "OKK", "1", ""})
        EXPECT_EQ(parse_reply(Command::reset, frame).error().code, Errc::malformed) << frame;
}

TEST(Id2, DeviceSide) {
    EXPECT_EQ(parse_request('I'), Command::stop_input);
    EXPECT_EQ(parse_request('C'), Command::count);
    EXPECT_EQ(parse_request('R'), Command::reset);
    EXPECT_FALSE(parse_request('i'));
    EXPECT_FALSE(parse_request('\n'));
    EXPECT_EQ(encode_count(42), "00042\n");
    EXPECT_EQ(encode_count(65535), "65535\n");
    EXPECT_EQ(encode_stop_input(true), "1\n");
    EXPECT_EQ(encode_reset_ok(), "OK\n");
}

TEST(Id2, ExchangeDecodesToOneWordOrNone) {
    const auto count = make_exchange(Command::count);
    EXPECT_EQ(count.request, "C");
    EXPECT_EQ(count.terminator, '\n');
    EXPECT_EQ(count.reply_length, 5u);
    const auto reading = decode(count, "01234");
    ASSERT_TRUE(reading);
    EXPECT_EQ(reading->count, 1);
    EXPECT_EQ(reading->raw[0], 1234);
    EXPECT_EQ(decode(make_exchange(Command::reset), "OK")->count, 0);
    EXPECT_EQ(describe(count.target), "ID-2 counter");
}

}  // namespace
}  // namespace ioport::id2
