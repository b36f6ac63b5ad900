// The Sparkplug store's files (daemon/sparkplug/store_files.hpp) on a real file system: what a
// restart finds after a clean stop, a torn tail, a flipped bit, a full store and a damaged mark;
// links planted in the directory, a directory others may write, a stray segment; and, through a
// directory of the test's own, a full disk.
#include "daemon/sparkplug/store_files.hpp"

#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>

#include <fmt/format.h>
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

TEST(StoreFiles, TheNextBdSeqIsKeptBesideTheRecordsAndOnlyAValidOneIsRead) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    {
        auto files = open_store(dir);
        ASSERT_TRUE(files.save_bdseq(17));
        ASSERT_TRUE(files.save_bdseq(18));  // replaced, never appended to
    }
    const auto read = [&] { return saved_bdseq(*DiskDirectory::open(dir).value()); };
    EXPECT_EQ(read(), 18U);
    EXPECT_FALSE(fs::exists(dir / "bdseq.tmp"));
    for (const std::string bad : {"256\n", "18", "-1\n", "x\n", "", "18\n\n", "0018888\n"}) {
        std::ofstream(dir / "bdseq", std::ios::trunc) << bad;
        EXPECT_EQ(read(), std::nullopt) << bad;
    }
    fs::remove(dir / "bdseq");
    EXPECT_EQ(read(), std::nullopt);
    auto files = open_store(dir);  // the file is no segment: the store opens as ever
    EXPECT_EQ(files.recovery().segments, 0U);
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

std::string contents(const fs::path& file) {
    std::ifstream in(file, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), {}};
}

// Issue 37: links planted in a store directory under a world-writable one made a root-run
// ioportd truncate and overwrite the files they pointed to. No store file is ever opened through
// a link: the mark's temporary file is replaced, and a segment that is a link is an error.
TEST(StoreFiles, ALinkPlantedInTheStoreIsNeverFollowed) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    const auto victim = temp.path() / "victim";
    std::ofstream(victim) << "precious";
    fs::create_directory(dir);
    fs::permissions(dir, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec);
    fs::create_symlink(victim, dir / "delivered.tmp");
    {
        auto files = open_store(dir);
        for (std::uint64_t n = 1; n <= 3; ++n)
            ASSERT_TRUE(files.append(body(n)));
        ASSERT_TRUE(files.deliver(2));
        ASSERT_TRUE(files.sync());  // writes the mark through delivered.tmp
    }
    EXPECT_EQ(contents(victim), "precious");
    EXPECT_FALSE(fs::is_symlink(dir / "delivered.tmp"));
    EXPECT_EQ(open_store(dir).delivered(), 2U);

    // A segment that is a link: the store does not open, and says which file.
    fs::create_symlink(victim, dir / "00000000000000000009.seg");
    const auto refused = StoreFiles::open(dir, one_mib);
    ASSERT_FALSE(refused);
    EXPECT_NE(refused.error().message.find("00000000000000000009.seg"), std::string::npos)
        << refused.error().message;
    EXPECT_EQ(contents(victim), "precious");
}

TEST(StoreFiles, ADirectoryOthersCanWriteIsRefused) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    fs::create_directory(dir);
    for (const auto mode : {01777, 0770, 0757}) {
        ASSERT_EQ(::chmod(dir.c_str(), static_cast<mode_t>(mode)), 0);
        const auto refused = StoreFiles::open(dir, one_mib);
        ASSERT_FALSE(refused) << std::oct << mode;
        EXPECT_EQ(refused.error().code, Errc::permission_denied);
        EXPECT_NE(
            refused.error().message.find(fmt::format(
                "is writable by {} (mode {:04o})", (mode & 2) != 0 ? "others" : "its group", mode)),
            std::string::npos)
            << refused.error().message;
        EXPECT_TRUE(check_store_directory(dir).error().message == refused.error().message);
    }
    ASSERT_EQ(::chmod(dir.c_str(), 0750), 0);
    EXPECT_TRUE(StoreFiles::open(dir, one_mib));
    EXPECT_TRUE(check_store_directory(temp.path() / "not yet"));  // made at opening
    EXPECT_FALSE(fs::exists(temp.path() / "not yet"));
}

TEST(StoreFiles, ADirectoryOfAnotherUserIsRefused) {
    if (::geteuid() != 0) GTEST_SKIP() << "only root can give the directory to another user";
    TempDir temp;
    const auto dir = temp.path() / "store";
    fs::create_directory(dir);
    fs::permissions(dir, fs::perms::owner_all);
    ASSERT_EQ(::chown(dir.c_str(), 65534, 65534), 0);  // nobody
    const auto refused = StoreFiles::open(dir, one_mib);
    ASSERT_FALSE(refused);
    EXPECT_NE(refused.error().message.find("belongs to user id 65534, not to the user ioportd "
                                           "runs as (id 0)"),
              std::string::npos)
        << refused.error().message;
}

// Issue 37: an empty file named above the next record number was appended to, and at the next
// start every record below its name was skipped: 23 stored, 0 forwarded, none counted dropped.
TEST(StoreFiles, AStraySegmentNamedAboveTheRecordsSwallowsNothing) {
    TempDir temp;
    const auto dir = temp.path() / "store";
    fill(dir, 3);
    std::ofstream(dir / "00000000000100000000.seg").flush();
    {
        auto files = open_store(dir);
        EXPECT_EQ(files.recovery().records, 3U);
        for (std::uint64_t n = 4; n <= 26; ++n)
            EXPECT_EQ(files.append(body(n)).value(), n);
        ASSERT_TRUE(files.sync());
    }
    auto files = open_store(dir);
    EXPECT_EQ(files.recovery().records, 26U);
    const auto numbers = numbers_after(files, 0);
    ASSERT_EQ(numbers.size(), 26U);
    EXPECT_EQ(numbers.front(), 1U);
    EXPECT_EQ(numbers.back(), 26U);
    EXPECT_EQ(files.counts().dropped, 0U);
    EXPECT_FALSE(fs::exists(dir / "00000000000100000000.seg"));
    // Names and marks beyond the numbers the store uses are not the store's.
    std::ofstream(dir / "99999999999999999999.seg").flush();
    EXPECT_EQ(open_store(dir).recovery().records, 26U);
}

// The disk, as DiskDirectory, until its segments hold `capacity` bytes: then a write takes what
// fits and fails with ENOSPC, as a full file system does.
class FullDisk final : public StoreDirectory {
  public:
    FullDisk(std::unique_ptr<StoreDirectory> disk, std::uint64_t capacity)
        : disk_(std::move(disk)), capacity_(capacity) {}

    Result<std::vector<std::string>> names() override { return disk_->names(); }
    Result<std::vector<std::uint8_t>> read(std::string_view name, std::uint64_t limit) override {
        return disk_->read(name, limit);
    }
    Result<std::uint64_t> size(std::string_view name) override { return disk_->size(name); }
    Result<File> open_append(std::string_view name, bool create) override {
        auto file = disk_->open_append(name, create);
        if (file) names_[*file] = std::string(name);
        if (file && create) sizes_[std::string(name)] = 0;
        return file;
    }
    Result<> write(File file, std::span<const std::uint8_t> bytes) override {
        auto& size = sizes_[names_.at(file)];
        const auto room = capacity_ - std::min(capacity_, used());
        if (bytes.size() <= room) {
            size += bytes.size();
            return disk_->write(file, bytes);
        }
        size += room;
        (void)disk_->write(file, bytes.first(room));
        ++full_;
        return fail(Errc::no_space, "No space left on device");
    }
    Result<> truncate(File file, std::uint64_t size) override {
        sizes_[names_.at(file)] = size;
        return disk_->truncate(file, size);
    }
    Result<> sync(File file) override { return disk_->sync(file); }
    void close(File file) override {
        names_.erase(file);
        disk_->close(file);
    }
    Result<> rename(std::string_view from, std::string_view to) override {
        return disk_->rename(from, to);
    }
    Result<> remove(std::string_view name) override {
        sizes_.erase(std::string(name));
        return disk_->remove(name);
    }
    Result<> sync_names() override { return disk_->sync_names(); }
    const std::filesystem::path& path() const override { return disk_->path(); }

    std::uint64_t full() const { return full_; }

  private:
    std::uint64_t used() const {
        std::uint64_t total = 0;
        for (const auto& [name, size] : sizes_)
            total += size;
        return total;
    }
    std::unique_ptr<StoreDirectory> disk_;
    std::uint64_t capacity_;
    std::map<File, std::string> names_;
    std::map<std::string, std::uint64_t> sizes_;
    std::uint64_t full_ = 0;
};

// Issue 37: on a full file system the store kept its oldest records and dropped 1,195 new ones.
// A full disk drops the oldest first, as max_size does, counted apart.
TEST(StoreFiles, AFullDiskDropsTheOldestAndKeepsTheNewest) {
    TempDir temp;
    auto directory = DiskDirectory::open(temp.path() / "store");
    ASSERT_TRUE(directory);
    auto disk = std::make_unique<FullDisk>(*std::move(directory), 4 * min_segment_bytes);
    auto& full = *disk;
    auto opened = StoreFiles::open(std::move(disk), one_mib);  // segments of 64 KiB
    ASSERT_TRUE(opened);
    auto& files = *opened;
    const std::size_t size = 1000;
    const std::uint64_t appended = 1000;  // about four times what the disk holds
    for (std::uint64_t n = 1; n <= appended; ++n)
        ASSERT_EQ(files.append(body(n, size)).value(), n);
    EXPECT_GT(full.full(), 0U);
    const auto counts = files.counts();
    EXPECT_GT(counts.dropped, appended / 2);
    EXPECT_EQ(counts.dropped_full, counts.dropped);
    EXPECT_EQ(counts.records + counts.dropped, appended);
    const auto kept = numbers_after(files, files.delivered());
    ASSERT_EQ(kept.size(), counts.records);
    EXPECT_EQ(kept.front(), counts.dropped + 1);  // the oldest went, in order
    EXPECT_EQ(kept.back(), appended);             // the newest are there
    EXPECT_LE(counts.bytes, 4 * min_segment_bytes);
}

}  // namespace
}  // namespace ioport::daemon
