// The records of the Sparkplug store (gateway.md §6.2) as bytes: pure functions, no I/O, so that
// recovery after a crash is tested and fuzzed over any bytes a torn or corrupted file can hold.
//
// A store is a directory of segment files, each an append-only run of records:
//
//   offset  size  field
//        0     4  magic "ioSR" (a record starts here)
//        4     4  length of the body, little-endian, at most max_record_body
//        8     8  number, little-endian: one more than the record before, across segments
//       16     4  CRC-32 (ISO-HDLC, as zlib's) of bytes 4..15 and the body, little-endian
//       20     n  body
//
// A crash or a power cut can leave the last record of a segment half written (a torn tail), and
// a failing card can flip bits anywhere. scan_segment() returns the records whose header and
// checksum hold, in order, and the byte ranges it skipped: garbage is never replayed as a record.
// After a bad stretch it resynchronises on the next magic whose record checks out.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace ioport::store {

inline constexpr std::size_t record_header_bytes = 20;
// A record is one DDATA message: a module's changed metrics, some hundreds of bytes.
inline constexpr std::size_t max_record_body = std::size_t{64} << 10;

// Appends one record to `out`. `body` must be at most max_record_body bytes.
void append_record(std::vector<std::uint8_t>& out, std::uint64_t number,
                   std::span<const std::uint8_t> body);

struct RecordView {
    std::uint64_t number = 0;
    std::size_t offset = 0;  // of its header in the segment
    std::span<const std::uint8_t> body;
};

struct SkippedBytes {
    std::size_t offset = 0;
    std::size_t bytes = 0;
};

struct SegmentScan {
    std::vector<RecordView> records;    // numbers strictly increasing
    std::vector<SkippedBytes> skipped;  // what is not a record: torn, corrupted, stale
    std::size_t valid_end = 0;          // the end of the last good record: where appending resumes
};

// Every good record of a segment's bytes. A record whose number is not above the one before is
// skipped with the bytes around it (stale data can carry a valid checksum).
SegmentScan scan_segment(std::span<const std::uint8_t> bytes);

}  // namespace ioport::store
