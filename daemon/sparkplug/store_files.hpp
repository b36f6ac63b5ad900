// The files of the Sparkplug store (gateway.md §6.2): a directory of segment files of records
// (protocol/store_segment.hpp) and a mark of what the broker is known to have.
//
//   <dir>/00000000000000000001.seg   records 1…, the name is the first record's number
//   <dir>/00000000000000004097.seg   …the newest segment, the only one appended to
//   <dir>/delivered                  the number of the last record the broker has (8 bytes LE,
//                                    then their CRC-32), written to delivered.tmp, synced and
//                                    renamed at each sync
//
// Every file operation goes through StoreDirectory (store_directory.hpp): by name, within the
// directory, never following a link. Every call blocks on the disk (an SD card can take seconds
// to sync): SparkplugStore calls them on its disk thread, never on the loop. Tested on real files
// without any thread, and on directories of the tests' own (a full disk).
//
// Durability: append() writes each record with write(2) at once, so a crash of the process loses
// nothing; sync() (once a second) makes them durable against a power cut (fdatasync), which so
// loses at most the last second. On open, every segment is scanned: a torn or corrupted stretch
// is skipped (and the newest segment truncated before it), never replayed. Whatever else the
// directory holds, a record that was appended is forwarded or counted dropped: records are
// numbered from one more than any found, and only a segment that ends right before that number
// is appended to. A full disk drops the oldest segments first, as max_size does.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "daemon/sparkplug/store_directory.hpp"
#include "protocol/error.hpp"
#include "protocol/store_segment.hpp"

namespace ioport::daemon {

struct StoredRecord {
    std::uint64_t number = 0;
    std::vector<std::uint8_t> body;
};

struct StoreCounts {
    std::uint64_t bytes = 0;         // of every segment on disk
    std::uint64_t records = 0;       // not yet delivered
    std::uint64_t dropped = 0;       // the oldest, since opening: beyond max_size or the disk full
    std::uint64_t dropped_full = 0;  // of those, for the disk full
    friend bool operator==(const StoreCounts&, const StoreCounts&) = default;
};

// What open() found, for the journal.
struct StoreRecovery {
    std::size_t segments = 0;
    std::uint64_t records = 0;        // waiting to be delivered
    std::uint64_t skipped_bytes = 0;  // torn or corrupted, not replayed
};

// Segments are a sixteenth of max_size, within these bounds: a full store drops its oldest
// sixteenth at a time, and a segment is read whole when forwarding.
inline constexpr std::uint64_t min_segment_bytes = std::uint64_t{64} << 10;
inline constexpr std::uint64_t max_segment_bytes = std::uint64_t{4} << 20;
std::uint64_t segment_bytes_for(std::uint64_t max_size);
// "00000000000000004097.seg" for 4097; nullopt for a name that is not a segment's. Numbers go no
// higher than max_record_number: a name or a mark beyond it is not the store's.
inline constexpr std::uint64_t max_record_number = std::uint64_t{1} << 62;
std::string segment_name(std::uint64_t first);
// The next bdSeq save_bdseq() kept in `dir`, if there is a valid one (0..255).
std::optional<std::uint64_t> saved_bdseq(StoreDirectory& dir);
std::optional<std::uint64_t> segment_number(std::string_view name);

class StoreFiles {
  public:
    // Reads the mark and scans every segment of `dir`.
    static Result<StoreFiles> open(std::unique_ptr<StoreDirectory> dir, std::uint64_t max_size);
    // The same on disk: DiskDirectory::open(dir) first (created when missing, refused when others
    // could write into it).
    static Result<StoreFiles> open(const std::filesystem::path& dir, std::uint64_t max_size);
    StoreFiles(StoreFiles&& other) noexcept;
    StoreFiles& operator=(StoreFiles&&) = delete;
    StoreFiles(const StoreFiles&) = delete;
    StoreFiles& operator=(const StoreFiles&) = delete;
    ~StoreFiles();

    // Appends one record as the next number; beyond max_size, or when the disk is full, the
    // oldest segments go first. Fails (nothing appended) when the disk does not take it.
    Result<std::uint64_t> append(std::span<const std::uint8_t> body);
    // Writes the mark, and makes what was appended durable (fdatasync, and the directory when
    // files came or went).
    Result<> sync();
    // Up to `count` records after `after`, oldest first, at most `max_bytes` of bodies (one at
    // least).
    Result<std::vector<StoredRecord>> read_after(std::uint64_t after, std::size_t count,
                                                 std::size_t max_bytes);
    // The broker has every record up to `through`: segments wholly delivered are deleted, and
    // the mark moves (written by the next sync(): a crash before it forwards again what the
    // broker has, never loses what it has not).
    Result<> deliver(std::uint64_t through);

    // Sparkplug's next bdSeq, kept beside the records so that a restart goes on from it
    // (issue 49): written to a temporary name and renamed, not synced (a power cut may repeat
    // one value, never lose the file).
    Result<> save_bdseq(std::uint64_t next);

    StoreCounts counts() const;
    std::uint64_t delivered() const { return delivered_; }
    const StoreRecovery& recovery() const { return recovery_; }

  private:
    struct Segment {
        std::uint64_t first = 0;  // the number in its name
        std::uint64_t last = 0;   // of its last record; first - 1 when empty
        std::uint64_t bytes = 0;
        std::uint64_t records = 0;
    };
    StoreFiles(std::unique_ptr<StoreDirectory> dir, std::uint64_t max_size);
    Result<> load();
    Result<> load_segment(std::uint64_t first);
    Result<> resume_newest();
    Result<std::uint64_t> append_once(std::span<const std::uint8_t> body);
    Result<> start_segment();
    Result<> drop_oldest();
    Result<> remove_segment(std::map<std::uint64_t, Segment>::iterator segment);
    Result<> write_mark();
    std::uint64_t pending_in(const Segment& segment) const;
    void close_writer();

    std::unique_ptr<StoreDirectory> dir_;
    std::uint64_t max_size_ = 0;
    std::uint64_t segment_bytes_ = 0;
    std::map<std::uint64_t, Segment> segments_;  // by first number
    StoreDirectory::File writer_ = -1;           // the newest segment, appended to
    std::uint64_t next_ = 1;
    std::uint64_t delivered_ = 0;
    std::uint64_t dropped_ = 0;
    std::uint64_t dropped_full_ = 0;
    bool data_dirty_ = false;
    bool dir_dirty_ = false;
    bool mark_dirty_ = false;  // delivered_ moved since the mark was written
    StoreRecovery recovery_;
    std::vector<std::uint8_t> buffer_;  // one record, reused
    // The last segment read_after() read and its records, while it has not grown: forwarding
    // reads a segment a batch at a time, and each batch is then a binary search.
    struct Cached {
        std::uint64_t first = 0;
        std::vector<std::uint8_t> bytes;
        std::vector<store::RecordView> records;  // into bytes
    };
    std::optional<Cached> cached_;
};

}  // namespace ioport::daemon
