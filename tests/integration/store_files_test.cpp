// The Sparkplug store's files (daemon/sparkplug/store_files.hpp) on a real file system: what a
// restart finds after a clean stop, a torn tail, a flipped bit, a full store and a damaged mark.
#include "daemon/sparkplug/store_files.hpp"

#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "protocol/store_segment.hpp"
#include "tests/support/process.hpp"

namespace ioport::daemon {
namespace {

namespace fs = std::filesystem;
using Bytes = std::vector<std::uint8_t>;
using test::TempDir;

constexpr std::uint64_t one_mib = std::uint64_t{1} << 20;

Bytes body(std::uint64_t n, std::size_t size = 8) {
    Bytes out(size, static_cast<std::uint8_t>(n));
    out[0] = static_cast<std::uint8_t>(n >> 8);
    return out;
}

StoreFiles open_store(const fs::path& dir, std::uint64_t max_size = one_mib) {
    auto files = StoreFiles::open(dir, max_size);
    EXPECT_TRUE(files) << (files ? "" : files.error().message);
    return std::move(*files);
}

std::vector<std::uint64_t> numbers_after(StoreFiles& files, std::uint64_t after,
                                         std::size_t count = 1000) {
    const auto records = files.read_after(after, count, std::size_t{64} << 20);
    EXPECT_TRUE(records) << (records ? "" : records.error().message);
    std::vector<std::uint64_t> out;
    for (const auto& record : *records)
        out.push_back(record.number);
    return out;
}

// A store of records 1..n, closed again: what a restart finds.
void fill(const fs::path& dir, std::uint64_t n) {
    auto files = open_store(dir);
    for (std::uint64_t i = 1; i <= n; ++i)
        ASSERT_TRUE(files.append(body(i)));
}

std::vector<fs::path> segments(const fs::path& dir) {
    std::vector<fs::path> out;
    for (const auto& entry : fs::directory_iterator(dir))
        if (entry.path().extension() == ".seg") out.push_back(entry.path());
    std::ranges::sort(out);
    return out;
}

TEST(StoreFiles, WhatWasAppendedIsThereAfterAReopen) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    {
        auto files = open_store(dir);
        for (std::uint64_t n = 1; n <= 3; ++n)
            EXPECT_EQ(files.append(body(n)).value(), n);
        ASSERT_TRUE(files.sync());
        EXPECT_EQ(files.counts(), (StoreCounts{3 * (store::record_header_bytes + 8), 3, 0}));
    }
    auto files = open_store(dir);
    EXPECT_EQ(files.recovery().records, 3U);
    EXPECT_EQ(files.recovery().skipped_bytes, 0U);
    const auto records = files.read_after(0, 10, one_mib).value();
    ASSERT_EQ(records.size(), 3U);
    EXPECT_EQ(records[1].number, 2U);
    EXPECT_EQ(records[1].body, body(2));
    EXPECT_EQ(files.append(body(4)).value(), 4U);  // numbering goes on
    EXPECT_EQ(numbers_after(files, 2), (std::vector<std::uint64_t>{3, 4}));
    EXPECT_EQ(numbers_after(files, 0, 2), (std::vector<std::uint64_t>{1, 2}));
}

TEST(StoreFiles, ATornTailIsCutAndAppendingResumesThere) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    fill(dir, 3);
    const auto segment = segments(dir).at(0);
    const auto whole = fs::file_size(segment);
    fs::resize_file(segment, whole - 5);  // the last record half written, as a crash leaves it
    auto files = open_store(dir);
    EXPECT_EQ(files.recovery().records, 2U);
    EXPECT_EQ(files.recovery().skipped_bytes, store::record_header_bytes + 8 - 5);
    EXPECT_EQ(fs::file_size(segment), 2 * (store::record_header_bytes + 8));
    EXPECT_EQ(files.append(body(3)).value(), 3U);
    EXPECT_EQ(numbers_after(files, 0), (std::vector<std::uint64_t>{1, 2, 3}));
}

TEST(StoreFiles, AFlippedBitLosesOneRecordNeverReplaysGarbage) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    fill(dir, 3);
    const auto segment = segments(dir).at(0);
    {
        std::fstream file(segment, std::ios::in | std::ios::out | std::ios::binary);
        file.seekp(static_cast<std::streamoff>(store::record_header_bytes + 8 +
                                               store::record_header_bytes + 3));
        file.put('\xFF');  // in the body of record 2
    }
    auto files = open_store(dir);
    EXPECT_EQ(files.recovery().records, 2U);
    EXPECT_EQ(files.recovery().skipped_bytes, store::record_header_bytes + 8);
    EXPECT_EQ(numbers_after(files, 0), (std::vector<std::uint64_t>{1, 3}));
}

TEST(StoreFiles, AFullStoreDropsItsOldestAndCountsThem) {
    TempDir temp;
    auto files = open_store(temp.path() / "store", one_mib);  // 16 segments of 64 KiB
    const std::size_t size = 1000;
    const std::uint64_t appended = 3 * one_mib / (store::record_header_bytes + size);
    for (std::uint64_t n = 1; n <= appended; ++n)
        ASSERT_TRUE(files.append(body(n, size)));
    const auto counts = files.counts();
    EXPECT_LE(counts.bytes, one_mib);
    EXPECT_GT(counts.bytes, one_mib - min_segment_bytes);
    EXPECT_EQ(counts.records + counts.dropped, appended);
    const auto oldest = numbers_after(files, 0, 1);
    ASSERT_EQ(oldest.size(), 1U);
    EXPECT_EQ(oldest[0], counts.dropped + 1);  // the oldest went, in order
    EXPECT_LE(segments(temp.path() / "store").size(), 16U);
}

TEST(StoreFiles, DeliveredRecordsGoAndTheMarkSurvivesAReopen) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    const std::size_t size = 4000;  // 16 records a 64 KiB segment
    {
        auto files = open_store(dir);
        for (std::uint64_t n = 1; n <= 40; ++n)
            ASSERT_TRUE(files.append(body(n, size)));
        ASSERT_EQ(segments(dir).size(), 3U);
        ASSERT_TRUE(files.deliver(20));
        EXPECT_EQ(files.counts().records, 20U);
        EXPECT_EQ(segments(dir).size(), 2U);  // records 1-16 are gone with their segment
        ASSERT_TRUE(files.sync());
    }
    auto files = open_store(dir);
    EXPECT_EQ(files.delivered(), 20U);
    EXPECT_EQ(files.recovery().records, 20U);
    EXPECT_EQ(numbers_after(files, files.delivered(), 1), std::vector<std::uint64_t>{21});
    ASSERT_TRUE(files.deliver(40));
    EXPECT_TRUE(segments(dir).empty());
    EXPECT_EQ(files.counts(), (StoreCounts{0, 0, 0}));
    EXPECT_EQ(files.append(body(41)).value(), 41U);  // a new segment, numbering goes on
    EXPECT_EQ(numbers_after(files, 40), std::vector<std::uint64_t>{41});
}

TEST(StoreFiles, ADamagedMarkForwardsEverythingAgainRatherThanLoseAny) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    {
        auto files = open_store(dir);
        for (std::uint64_t n = 1; n <= 3; ++n)
            ASSERT_TRUE(files.append(body(n)));
        ASSERT_TRUE(files.deliver(2));
        ASSERT_TRUE(files.sync());  // writes the mark
    }
    ASSERT_EQ(StoreFiles::open(dir, one_mib)->delivered(), 2U);
    {
        std::fstream mark(dir / "delivered", std::ios::in | std::ios::out | std::ios::binary);
        mark.put('\x07');
    }
    auto files = open_store(dir);
    EXPECT_EQ(files.delivered(), 0U);
    EXPECT_EQ(numbers_after(files, 0), (std::vector<std::uint64_t>{1, 2, 3}));
}

TEST(StoreFiles, ADirectoryThatCannotBeMadeIsAnErrorNamingIt) {
    TempDir temp;
    std::ofstream(temp.path() / "file") << "x";
    const auto files = StoreFiles::open(temp.path() / "file" / "store", one_mib);
    ASSERT_FALSE(files);
    EXPECT_NE(files.error().message.find(temp / "file/store"), std::string::npos)
        << files.error().message;
    EXPECT_NE(files.error().message.find("Not a directory"), std::string::npos)
        << files.error().message;
}

TEST(StoreFiles, ARecordTooLargeIsRefused) {
    TempDir temp;
    auto files = open_store(temp.path() / "store");
    const auto refused = files.append(Bytes(store::max_record_body + 1));
    ASSERT_FALSE(refused);
    EXPECT_EQ(refused.error().code, Errc::invalid_argument);
    EXPECT_EQ(files.counts().records, 0U);
}

}  // namespace
}  // namespace ioport::daemon
