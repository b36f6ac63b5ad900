#include "protocol/store_segment.hpp"

#include <string_view>

#include <gtest/gtest.h>

namespace {

using ioport::store::append_record;
using ioport::store::scan_segment;
using Bytes = std::vector<std::uint8_t>;

Bytes text(std::string_view s) {
    return {s.begin(), s.end()};
}

Bytes segment_of(std::initializer_list<std::pair<std::uint64_t, std::string_view>> records) {
    Bytes out;
    for (const auto& [number, body] : records)
        append_record(out, number, text(body));
    return out;
}

std::vector<std::uint64_t> numbers(const ioport::store::SegmentScan& scan) {
    std::vector<std::uint64_t> out;
    for (const auto& record : scan.records)
        out.push_back(record.number);
    return out;
}

TEST(StoreSegment, ARecordToTheByte) {
    Bytes out;
    append_record(out, 1, text("ab"));
    const Bytes expected{
        'i',  'o',  'S',  'R',                           // magic
        0x02, 0x00, 0x00, 0x00,                          // body length 2
        0x01, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,  // number 1
        0xC6, 0x8C, 0x4D, 0x00,  // CRC-32 of bytes 4..15 and the body (zlib's)
        'a',  'b',               // body
    };
    EXPECT_EQ(out, expected);
}

TEST(StoreSegment, ScansWhatWasAppended) {
    const auto bytes = segment_of({{7, "first"}, {8, ""}, {9, "third"}});
    const auto scan = scan_segment(bytes);
    EXPECT_EQ(numbers(scan), (std::vector<std::uint64_t>{7, 8, 9}));
    EXPECT_EQ(Bytes(scan.records[0].body.begin(), scan.records[0].body.end()), text("first"));
    EXPECT_TRUE(scan.records[1].body.empty());
    EXPECT_EQ(scan.records[2].offset, 2 * ioport::store::record_header_bytes + 5);
    EXPECT_TRUE(scan.skipped.empty());
    EXPECT_EQ(scan.valid_end, bytes.size());
}

TEST(StoreSegment, ATornTailIsSkippedAndAppendingResumesBeforeIt) {
    const auto whole = segment_of({{1, "one"}, {2, "two"}});
    const auto first_end = ioport::store::record_header_bytes + 3;
    // Every place a crash can cut the second record.
    for (std::size_t cut = first_end + 1; cut < whole.size(); ++cut) {
        const auto scan = scan_segment(std::span(whole).first(cut));
        EXPECT_EQ(numbers(scan), std::vector<std::uint64_t>{1}) << "cut at " << cut;
        EXPECT_EQ(scan.valid_end, first_end) << "cut at " << cut;
        ASSERT_EQ(scan.skipped.size(), 1U) << "cut at " << cut;
        EXPECT_EQ(scan.skipped[0].offset, first_end);
        EXPECT_EQ(scan.skipped[0].bytes, cut - first_end);
    }
}

TEST(StoreSegment, AFlippedBitLosesOnlyItsRecord) {
    auto bytes = segment_of({{1, "one"}, {2, "two"}, {3, "three"}});
    const auto second = ioport::store::record_header_bytes + 3;
    // Any bit of the second record: magic, length, number, checksum or body.
    for (std::size_t byte = second; byte < second + ioport::store::record_header_bytes + 3;
         ++byte) {
        for (int bit = 0; bit < 8; ++bit) {
            auto damaged = bytes;
            damaged[byte] ^= static_cast<std::uint8_t>(1 << bit);
            const auto scan = scan_segment(damaged);
            EXPECT_EQ(numbers(scan), (std::vector<std::uint64_t>{1, 3}))
                << "byte " << byte << " bit " << bit;
            EXPECT_EQ(scan.valid_end, bytes.size());
        }
    }
}

TEST(StoreSegment, GarbageBetweenRecordsIsSkippedInOneRange) {
    auto bytes = segment_of({{1, "one"}});
    const auto garbage_at = bytes.size();
    const Bytes garbage{'i', 'o', 'S', 0x00, 'i', 0xFF, 'i', 'o', 'S', 'R', 0x01};
    bytes.insert(bytes.end(), garbage.begin(), garbage.end());
    append_record(bytes, 2, text("two"));
    const auto scan = scan_segment(bytes);
    EXPECT_EQ(numbers(scan), (std::vector<std::uint64_t>{1, 2}));
    ASSERT_EQ(scan.skipped.size(), 1U);
    EXPECT_EQ(scan.skipped[0].offset, garbage_at);
    EXPECT_EQ(scan.skipped[0].bytes, garbage.size());
}

TEST(StoreSegment, AStaleRecordWithAGoodChecksumIsNotReplayed) {
    // A number at or below the one before: left over from older contents, never a new record.
    const auto bytes = segment_of({{5, "new"}, {3, "stale"}, {6, "next"}});
    EXPECT_EQ(numbers(scan_segment(bytes)), (std::vector<std::uint64_t>{5, 6}));
}

TEST(StoreSegment, ALengthBeyondTheLimitIsNotARecord) {
    Bytes bytes{'i', 'o', 'S', 'R', 0xFF, 0xFF, 0xFF, 0xFF};
    bytes.resize(64);
    const auto scan = scan_segment(bytes);
    EXPECT_TRUE(scan.records.empty());
    EXPECT_EQ(scan.valid_end, 0U);
    ASSERT_EQ(scan.skipped.size(), 1U);
    EXPECT_EQ(scan.skipped[0].bytes, 64U);
}

TEST(StoreSegment, NothingIsNothing) {
    const auto scan = scan_segment({});
    EXPECT_TRUE(scan.records.empty());
    EXPECT_TRUE(scan.skipped.empty());
    EXPECT_EQ(scan.valid_end, 0U);
}

}  // namespace
