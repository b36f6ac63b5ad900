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

TEST(Bytes, PlainOrInPowersOf1024) {
    EXPECT_EQ(parse_bytes("65536", ~0UL), 65536u);
    EXPECT_EQ(parse_bytes("64KiB", ~0UL), 64u << 10);
    EXPECT_EQ(parse_bytes("64MiB", ~0UL), 64u << 20);
    EXPECT_EQ(parse_bytes("2GiB", ~0UL), 2UL << 30);
    EXPECT_EQ(parse_bytes("0", ~0UL), 0u);
    EXPECT_EQ(parse_bytes("1GiB", 1UL << 30), 1UL << 30);
}

TEST(Bytes, RejectsAnythingElse) {
    for (const auto* text : {"", "MiB", "64 MiB", "64MB", "64mib", "64M", "0x10", "-1", "1.5MiB",
                             "64MiBMiB", "64KiBMiB", "64MiBKiB"})
        EXPECT_FALSE(parse_bytes(text, ~0UL)) << text;
    EXPECT_FALSE(parse_bytes("1025KiB", 1UL << 20));
    EXPECT_FALSE(parse_bytes("99999999999999999999GiB", ~0UL));
    EXPECT_FALSE(parse_bytes("17179869184GiB", ~0UL));  // 2^34 GiB = 2^64 bytes
}

}  // namespace
}  // namespace ioport
