// The labels of /metrics' Modbus families (gateway.md §5.4): only configured units and the
// function codes of §3.5 have values of their own, whatever clients send.
#include <cstdint>
#include <set>
#include <vector>

#include <gtest/gtest.h>

#include "protocol/request_labels.hpp"

namespace ioport::gateway {
namespace {

using Bytes = std::vector<std::uint8_t>;

TEST(RequestLabels, OnlyTheFunctionCodesOfSection35HaveTheirOwnLabel) {
    const std::set<int> own{1, 2, 3, 4, 5, 6, 15, 16, 23, 43};
    for (int function = 0; function < 256; ++function) {
        SCOPED_TRACE(function);
        EXPECT_EQ(function_label(static_cast<std::uint8_t>(function)),
                  own.contains(function) ? function : other_label);
    }
}

TEST(RequestLabels, ConfiguredUnitsKeepTheirIdAndNoUnitIsOther) {
    EXPECT_EQ(unit_label(1), 1);
    EXPECT_EQ(unit_label(247), 247);
    EXPECT_EQ(unit_label(-1), other_label);  // no link has the unit id asked for
    EXPECT_EQ(unit_label(0), other_label);
    EXPECT_EQ(unit_label(255), other_label);
}

TEST(RequestLabels, ExceptionCodesAreTheServersOwnOrOther) {
    const std::set<int> own{1, 2, 3, 4, 6, 10, 11};
    for (int code = 0; code < 256; ++code) {
        SCOPED_TRACE(code);
        EXPECT_EQ(exception_label(static_cast<std::uint8_t>(code)),
                  own.contains(code) ? code : other_label);
    }
}

TEST(RequestLabels, TextIsTheNumberInDecimalOrOther) {
    EXPECT_EQ(label_text(3), "3");
    EXPECT_EQ(label_text(43), "43");
    EXPECT_EQ(label_text(other_label), "other");
}

// The attack of issue 23: every unit id with every function code, from one client.
TEST(RequestCounts, EveryUnitAndFunctionAddsAtMostTheConfiguredUnitsAndOther) {
    RequestCounts counts;
    std::uint64_t sent = 0;
    for (int unit = 0; unit < 256; ++unit)
        for (int function = 0; function < 256; ++function) {
            // Unit 1 is configured (and reached by 0 and 255 too, the single-link aliases).
            const int answered_by = unit == 1 || unit == 0 || unit == 255 ? 1 : -1;
            const auto code = static_cast<std::uint8_t>(answered_by < 0 ? 0x0A : 0x01);
            counts.count(answered_by, static_cast<std::uint8_t>(function),
                         Bytes{static_cast<std::uint8_t>(function | 0x80), code});
            ++sent;
        }
    EXPECT_EQ(counts.requests().size(), 2U * 11U);
    std::uint64_t counted = 0;
    for (const auto& [key, count] : counts.requests()) {
        EXPECT_TRUE(key.first == 1 || key.first == other_label) << key.first;
        counted += count;
    }
    EXPECT_EQ(counted, sent);
    EXPECT_EQ(counts.requests().at({1, 3}), 3U);  // units 0, 1 and 255
    EXPECT_EQ(counts.requests().at({other_label, 3}), 253U);
    EXPECT_EQ(counts.requests().at({1, other_label}), 3U * 246U);
    EXPECT_EQ(counts.exceptions().size(), 2U);
    EXPECT_EQ(counts.exceptions().at({1, 1}), 3U * 256U);
    EXPECT_EQ(counts.exceptions().at({other_label, 10}), 253U * 256U);
}

TEST(RequestCounts, ANormalResponseIsNoException) {
    RequestCounts counts;
    counts.count(2, 3, Bytes{0x03, 0x02, 0x00, 0x07});
    counts.count(2, 3, Bytes{0x83});  // too short to carry a code
    EXPECT_EQ(counts.requests().at({2, 3}), 2U);
    EXPECT_TRUE(counts.exceptions().empty());
}

}  // namespace
}  // namespace ioport::gateway
