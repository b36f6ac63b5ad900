// Fuzz target: a segment file of the Sparkplug store as a crash, a power cut or a failing card
// can leave it, read back as the store does when it opens (protocol/store_segment.hpp).
//
// Input: the file's bytes. Invariants: the good records and the skipped ranges partition the
// bytes in order; numbers strictly increase; each record encodes back to its own bytes (so
// nothing but what append_record wrote is ever a record); appending after valid_end and scanning
// again finds the same records and the new one.
#include <algorithm>
#include <cstdint>
#include <vector>

#include "fuzz/fuzz.hpp"
#include "protocol/store_segment.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace ioport;
    using fuzz::check;
    const std::span<const std::uint8_t> bytes(data, size);
    const auto scan = store::scan_segment(bytes);

    std::size_t offset = 0;
    std::size_t record = 0;
    std::size_t skipped = 0;
    while (offset < size) {
        if (record < scan.records.size() && scan.records[record].offset == offset) {
            const auto& view = scan.records[record];
            check(record == 0 || view.number > scan.records[record - 1].number,
                  "record numbers strictly increase");
            std::vector<std::uint8_t> again;
            store::append_record(again, view.number, view.body);
            check(bytes.subspan(offset, again.size()).size() == again.size() &&
                      std::equal(again.begin(), again.end(), bytes.begin() + offset),
                  "a record is the bytes append_record writes for it");
            offset += again.size();
            ++record;
        } else {
            check(skipped < scan.skipped.size() && scan.skipped[skipped].offset == offset &&
                      scan.skipped[skipped].bytes > 0,
                  "what is not a record is one skipped range");
            offset += scan.skipped[skipped].bytes;
            ++skipped;
        }
    }
    check(offset == size && record == scan.records.size() && skipped == scan.skipped.size(),
          "records and skipped ranges cover the bytes exactly");
    check(scan.valid_end == (scan.records.empty()
                                 ? 0
                                 : scan.records.back().offset + store::record_header_bytes +
                                       scan.records.back().body.size()),
          "valid_end is the end of the last record");

    // The store appends after valid_end (it truncates the tail first).
    std::vector<std::uint8_t> resumed(data, data + scan.valid_end);
    const std::uint64_t next = scan.records.empty() ? 1 : scan.records.back().number + 1;
    if (next == 0) return 0;  // the last number there is
    store::append_record(resumed, next, bytes.first(std::min<std::size_t>(size, 16)));
    const auto rescan = store::scan_segment(resumed);
    check(rescan.records.size() == scan.records.size() + 1 &&
              rescan.records.back().number == next && rescan.valid_end == resumed.size(),
          "after truncating the tail, an appended record is found with all the others");
    return 0;
}
