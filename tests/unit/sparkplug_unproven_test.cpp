// The edge node's bookkeeping of live DDATA the broker has not provably read (UnprovenData):
// what a proof lets go, what a lost connection stores, and its bound.
#include "daemon/sparkplug/unproven.hpp"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace ioport::daemon {
namespace {

using sparkplug::Metric;
using sparkplug::Payload;
using sparkplug::StoredData;
using sparkplug::Value;

constexpr std::uint32_t boolean = 11;
constexpr std::uint32_t uint16 = 6;
constexpr std::uint32_t float32 = 9;

SentData word(std::uint64_t timestamp, std::uint64_t value) {
    return {"hub0.dim16.0", ModuleType::dim16, timestamp, {{16, gateway::PointValue(value)}}};
}

StoredData stored_word(std::uint64_t timestamp, std::uint64_t value) {
    return {"hub0.dim16.0",
            Payload{timestamp,
                    std::nullopt,
                    {Metric{"word", std::nullopt, timestamp, uint16, Value(value)}}}};
}

TEST(SparkplugUnproven, ALostConnectionStoresWhatWasSentInOrderByName) {
    UnprovenData unproven;
    EXPECT_EQ(unproven.mark(), 0U);
    unproven.sent({"hub0.dim16.0",
                   ModuleType::dim16,
                   100,
                   {{3, gateway::PointValue(true)}, {16, gateway::PointValue(std::uint64_t{8})}}});
    unproven.sent(
        {"hub0.acm3p.0",
         ModuleType::acm3p,
         101,
         {{2, gateway::PointValue(std::uint64_t{2000})}, {5, gateway::PointValue(1.5F)}}});
    unproven.sent({"press.id2", std::nullopt, 102, {{1, std::nullopt}}});
    EXPECT_EQ(unproven.mark(), 3U);
    EXPECT_EQ(unproven.size(), 3U);
    const auto records = unproven.take();
    const std::vector<StoredData> expected{
        {"hub0.dim16.0",
         Payload{100,
                 std::nullopt,
                 {Metric{"in/3", std::nullopt, 100, boolean, Value(true)},
                  Metric{"word", std::nullopt, 100, uint16, Value(std::uint64_t{8})}}}},
        {"hub0.acm3p.0",
         Payload{101,
                 std::nullopt,
                 {Metric{"raw/2", std::nullopt, 101, uint16, Value(std::uint64_t{2000})},
                  Metric{"value/2", std::nullopt, 101, float32, Value(1.5F)}}}},
        {"press.id2",
         Payload{102, std::nullopt, {Metric{"count", std::nullopt, 102, uint16, std::nullopt}}}},
    };
    EXPECT_EQ(records, expected);
    // What a store record is: each decodes back as it was.
    for (const auto& record : records)
        EXPECT_EQ(sparkplug::decode_stored(sparkplug::encode_stored(record)).value(), record);
    EXPECT_TRUE(unproven.empty());
    EXPECT_EQ(unproven.bytes(), 0U);
    EXPECT_TRUE(unproven.take().empty()) << "stored once";
    unproven.sent(word(103, 1));
    EXPECT_EQ(unproven.mark(), 4U) << "numbers go on";
}

TEST(SparkplugUnproven, AProofLetsGoWhatWasSentBeforeItsRoundTripOnly) {
    UnprovenData unproven;
    unproven.sent(word(1, 1));
    unproven.sent(word(2, 2));
    const auto proof = unproven.mark();  // a SUBSCRIBE goes out here
    unproven.sent(word(3, 3));           // after it: its SUBACK proves nothing of this one
    unproven.proven(proof);
    EXPECT_EQ(unproven.take(), std::vector{stored_word(3, 3)});
    unproven.sent(word(4, 4));
    unproven.proven(unproven.mark());
    EXPECT_TRUE(unproven.empty());
    EXPECT_EQ(unproven.bytes(), 0U);
    unproven.proven(unproven.mark());  // a late or repeated proof changes nothing
    EXPECT_TRUE(unproven.take().empty());
}

TEST(SparkplugUnproven, BeyondItsBoundTheOldestAreForgottenAndCounted) {
    UnprovenData probe;
    probe.sent(word(0, 0));
    const auto one = probe.bytes();
    ASSERT_GT(one, 0U);
    UnprovenData unproven(one * 3);
    for (std::uint64_t i = 1; i <= 5; ++i)
        unproven.sent(word(i, i));
    EXPECT_EQ(unproven.size(), 3U);
    EXPECT_LE(unproven.bytes(), one * 3);
    EXPECT_EQ(unproven.forgotten(), 2U);
    EXPECT_EQ(unproven.mark(), 5U);
    EXPECT_EQ(unproven.take(),
              (std::vector{stored_word(3, 3), stored_word(4, 4), stored_word(5, 5)}));
    // The default bound is the documented one, and holds thousands of small DDATA.
    UnprovenData bounded;
    for (std::uint64_t i = 0; i < 100'000; ++i)
        bounded.sent(word(i, i));
    EXPECT_LE(bounded.bytes(), max_unproven_bytes);
    EXPECT_GT(bounded.size(), 1000U);
    EXPECT_EQ(bounded.forgotten() + bounded.size(), 100'000U);
}

}  // namespace
}  // namespace ioport::daemon
