#include <gtest/gtest.h>

#include "config/number.hpp"

namespace ioport {
namespace {

TEST(Number, DecimalHexAndBinary) {
    EXPECT_EQ(parse_unsigned("37841", 65535), 37841u);
    EXPECT_EQ(parse_unsigned("0x93D1", 65535), 0x93D1u);
    EXPECT_EQ(parse_unsigned("0X93d1", 65535), 0x93D1u);
    EXPECT_EQ(parse_unsigned("0b1001001111010001", 65535), 0x93D1u);
    EXPECT_EQ(parse_unsigned("0", 0), 0u);
}

TEST(Number, RejectsAnythingElse) {
    for (const auto* text : {"", "0x", "0b", "-1", "+1", "1.0", "12a", " 1", "1 ", "0b2", "0xG"})
        EXPECT_FALSE(parse_unsigned(text, 65535)) << text;
    EXPECT_FALSE(parse_unsigned("65536", 65535));
    EXPECT_FALSE(parse_unsigned("99999999999999999999999", ~0UL));
}

}  // namespace
}  // namespace ioport
