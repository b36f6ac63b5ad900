#include "protocol/store_segment.hpp"

#include <algorithm>
#include <array>
#include <cassert>
#include <optional>

#include <boost/crc.hpp>
#include <boost/endian/conversion.hpp>

namespace ioport::store {
namespace {

namespace endian = boost::endian;

constexpr std::array<std::uint8_t, 4> magic{'i', 'o', 'S', 'R'};

std::uint32_t checksum(std::span<const std::uint8_t> length_and_number,
                       std::span<const std::uint8_t> body) {
    boost::crc_32_type crc;
    crc.process_bytes(length_and_number.data(), length_and_number.size());
    crc.process_bytes(body.data(), body.size());
    return crc.checksum();
}

// The record at `offset`, when its header and checksum hold and its number is above `after`.
std::optional<RecordView> record_at(std::span<const std::uint8_t> bytes, std::size_t offset,
                                    std::optional<std::uint64_t> after) {
    const auto rest = bytes.subspan(offset);
    if (rest.size() < record_header_bytes || !std::equal(magic.begin(), magic.end(), rest.begin()))
        return std::nullopt;
    const auto length = endian::load_little_u32(rest.data() + 4);
    if (length > max_record_body || rest.size() - record_header_bytes < length) return std::nullopt;
    const auto number = endian::load_little_u64(rest.data() + 8);
    if (after && number <= *after) return std::nullopt;
    const auto body = rest.subspan(record_header_bytes, length);
    if (endian::load_little_u32(rest.data() + 16) != checksum(rest.subspan(4, 12), body))
        return std::nullopt;
    return RecordView{number, offset, body};
}

}  // namespace

void append_record(std::vector<std::uint8_t>& out, std::uint64_t number,
                   std::span<const std::uint8_t> body) {
    assert(body.size() <= max_record_body);
    const auto start = out.size();
    out.resize(start + record_header_bytes);
    std::copy(magic.begin(), magic.end(), out.begin() + static_cast<std::ptrdiff_t>(start));
    endian::store_little_u32(out.data() + start + 4, static_cast<std::uint32_t>(body.size()));
    endian::store_little_u64(out.data() + start + 8, number);
    out.insert(out.end(), body.begin(), body.end());
    const std::span<const std::uint8_t> header(out.data() + start + 4, 12);
    const auto crc = checksum(header, std::span(out).subspan(start + record_header_bytes));
    endian::store_little_u32(out.data() + start + 16, crc);
}

SegmentScan scan_segment(std::span<const std::uint8_t> bytes) {
    SegmentScan scan;
    std::optional<std::uint64_t> last;
    std::size_t offset = 0;
    const auto skip_to = [&](std::size_t next) {
        if (!scan.skipped.empty() &&
            scan.skipped.back().offset + scan.skipped.back().bytes == offset)
            scan.skipped.back().bytes += next - offset;
        else
            scan.skipped.push_back({offset, next - offset});
        offset = next;
    };
    while (offset < bytes.size()) {
        if (const auto record = record_at(bytes, offset, last)) {
            scan.records.push_back(*record);
            last = record->number;
            offset += record_header_bytes + record->body.size();
            scan.valid_end = offset;
            continue;
        }
        // Not a record here: on to the next place the magic's first byte appears.
        const auto next = std::find(bytes.begin() + static_cast<std::ptrdiff_t>(offset) + 1,
                                    bytes.end(), magic[0]);
        skip_to(static_cast<std::size_t>(next - bytes.begin()));
    }
    return scan;
}

}  // namespace ioport::store
