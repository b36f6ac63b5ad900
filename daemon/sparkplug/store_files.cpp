#include "daemon/sparkplug/store_files.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <utility>

#include <fmt/format.h>
#include <boost/crc.hpp>
#include <boost/endian/conversion.hpp>

#include "protocol/store_segment.hpp"

namespace ioport::daemon {
namespace {

namespace endian = boost::endian;

constexpr std::string_view segment_suffix = ".seg";
constexpr std::size_t name_digits = 20;
constexpr std::string_view mark_name = "delivered";
constexpr std::string_view mark_temporary = "delivered.tmp";
constexpr std::size_t mark_bytes = 12;
constexpr std::string_view bdseq_name = "bdseq";
constexpr std::string_view bdseq_temporary = "bdseq.tmp";

std::uint32_t crc32(std::span<const std::uint8_t> bytes) {
    boost::crc_32_type crc;
    crc.process_bytes(bytes.data(), bytes.size());
    return crc.checksum();
}

}  // namespace

std::string segment_name(std::uint64_t first) {
    return fmt::format("{:0{}}{}", first, name_digits, segment_suffix);
}

std::optional<std::uint64_t> saved_bdseq(StoreDirectory& dir) {
    const auto bytes = dir.read(bdseq_name, 8);
    if (!bytes) return std::nullopt;
    const std::string_view text(reinterpret_cast<const char*>(bytes->data()), bytes->size());
    std::uint64_t next = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), next);
    if (ec != std::errc{} || end == text.data() || next > 255 ||
        std::string_view(end, text.data() + text.size()) != "\n")
        return std::nullopt;
    return next;
}

std::optional<std::uint64_t> segment_number(std::string_view name) {
    if (name.size() != name_digits + segment_suffix.size() || !name.ends_with(segment_suffix))
        return std::nullopt;
    std::uint64_t number = 0;
    const auto [end, ec] = std::from_chars(name.data(), name.data() + name_digits, number);
    if (ec != std::errc{} || end != name.data() + name_digits || number == 0 ||
        number > max_record_number)
        return std::nullopt;
    return number;
}

std::uint64_t segment_bytes_for(std::uint64_t max_size) {
    return std::clamp(max_size / 16, min_segment_bytes, max_segment_bytes);
}

StoreFiles::StoreFiles(std::unique_ptr<StoreDirectory> dir, std::uint64_t max_size)
    : dir_(std::move(dir)), max_size_(max_size), segment_bytes_(segment_bytes_for(max_size)) {}

StoreFiles::StoreFiles(StoreFiles&& other) noexcept
    : dir_(std::move(other.dir_)),
      max_size_(other.max_size_),
      segment_bytes_(other.segment_bytes_),
      segments_(std::move(other.segments_)),
      writer_(std::exchange(other.writer_, -1)),
      next_(other.next_),
      delivered_(other.delivered_),
      dropped_(other.dropped_),
      dropped_full_(other.dropped_full_),
      data_dirty_(other.data_dirty_),
      dir_dirty_(other.dir_dirty_),
      mark_dirty_(other.mark_dirty_),
      recovery_(other.recovery_),
      cached_(std::move(other.cached_)) {}

StoreFiles::~StoreFiles() {
    close_writer();
}

Result<StoreFiles> StoreFiles::open(std::unique_ptr<StoreDirectory> dir, std::uint64_t max_size) {
    StoreFiles files(std::move(dir), max_size);
    if (auto loaded = files.load(); !loaded) return Unexpected(loaded.error());
    return files;
}

Result<StoreFiles> StoreFiles::open(const std::filesystem::path& dir, std::uint64_t max_size) {
    auto directory = DiskDirectory::open(dir);
    if (!directory) return Unexpected(directory.error());
    return open(*std::move(directory), max_size);
}

std::uint64_t StoreFiles::pending_in(const Segment& segment) const {
    if (segment.records == 0 || delivered_ >= segment.last) return 0;
    if (delivered_ < segment.first) return segment.records;
    // Numbers within a segment are consecutive: append() numbers only what it wrote.
    return std::min(segment.records, segment.last - delivered_);
}

Result<> StoreFiles::load() {
    // The mark: a missing or damaged one means nothing is known delivered (duplicates, no loss).
    if (auto mark = dir_->read(mark_name, mark_bytes);
        mark && mark->size() == mark_bytes &&
        endian::load_little_u32(mark->data() + 8) == crc32(std::span(*mark).first(8)) &&
        endian::load_little_u64(mark->data()) <= max_record_number)
        delivered_ = endian::load_little_u64(mark->data());

    const auto names = dir_->names();
    if (!names) return Unexpected(names.error());
    std::vector<std::uint64_t> firsts;
    for (const auto& name : *names)
        if (const auto first = segment_number(name)) firsts.push_back(*first);
    std::ranges::sort(firsts);
    for (const auto first : firsts)
        if (auto loaded = load_segment(first); !loaded) return loaded;

    std::uint64_t last = 0;
    for (const auto& [first, segment] : segments_)
        if (segment.records > 0) last = std::max(last, segment.last);
    next_ = std::max(last, delivered_) + 1;
    recovery_.segments = segments_.size();
    // Wholly delivered segments left by a crash before their deletion, and segments holding no
    // record (the newest one's can only be a file that is not the store's, named above any
    // record: appending there would number records below its name).
    for (auto it = segments_.begin(); it != segments_.end();) {
        auto next = std::next(it);
        if (it->second.records == 0 || it->second.last <= delivered_)
            if (auto removed = remove_segment(it); !removed) return removed;
        it = next;
    }
    recovery_.records = counts().records;
    return resume_newest();
}

Result<> StoreFiles::load_segment(std::uint64_t first) {
    const auto name = segment_name(first);
    // A segment is at most segment_bytes_ and one more record; more is not this store's.
    const auto limit = segment_bytes_ + store::record_header_bytes + store::max_record_body;
    auto bytes = dir_->read(name, limit);
    if (!bytes) return Unexpected(bytes.error());
    const std::uint64_t size = bytes->size();
    if (const auto whole = dir_->size(name); whole && *whole > size)
        recovery_.skipped_bytes += *whole - size;

    const auto scan = store::scan_segment(*bytes);
    std::uint64_t previous = segments_.empty() ? 0 : segments_.rbegin()->second.last;
    Segment segment{first, first - 1, scan.valid_end, 0};
    std::uint64_t good_bytes = 0;
    for (const auto& record : scan.records) {
        // Numbers below the name or not above the segment before: not this segment's.
        if (record.number < first || record.number <= previous || record.number > max_record_number)
            continue;
        previous = record.number;
        segment.last = record.number;
        ++segment.records;
        good_bytes += store::record_header_bytes + record.body.size();
    }
    recovery_.skipped_bytes += size - good_bytes;
    segments_[first] = segment;
    return {};
}

// Appending goes on in the newest segment when it ends right before the next number and has
// room: its torn tail (a power cut) is cut through the descriptor first.
Result<> StoreFiles::resume_newest() {
    if (segments_.empty()) return {};
    auto& newest = segments_.rbegin()->second;
    if (newest.last + 1 != next_ || newest.bytes >= segment_bytes_) return {};
    const auto file = dir_->open_append(segment_name(newest.first), false);
    if (!file) return Unexpected(file.error());
    writer_ = *file;
    const auto size = dir_->size(segment_name(newest.first));
    if (size && *size > newest.bytes) {
        if (auto cut = dir_->truncate(writer_, newest.bytes); !cut) return cut;
        data_dirty_ = true;
    }
    return {};
}

void StoreFiles::close_writer() {
    if (writer_ < 0) return;
    dir_->close(writer_);
    writer_ = -1;
}

Result<> StoreFiles::start_segment() {
    // What the old segment got is made durable before it is left.
    if (auto synced = sync(); !synced) return synced;
    close_writer();
    const auto file = dir_->open_append(segment_name(next_), true);
    if (!file) return Unexpected(file.error());
    writer_ = *file;
    segments_[next_] = Segment{next_, next_ - 1, 0, 0};
    dir_dirty_ = true;
    return {};
}

Result<> StoreFiles::remove_segment(std::map<std::uint64_t, Segment>::iterator segment) {
    if (std::next(segment) == segments_.end()) close_writer();
    const auto name = segment_name(segment->first);
    if (cached_ && cached_->first == segment->first) cached_.reset();
    segments_.erase(segment);
    dir_dirty_ = true;
    return dir_->remove(name);
}

Result<> StoreFiles::drop_oldest() {
    const auto oldest = segments_.begin();
    dropped_ += pending_in(oldest->second);
    if (oldest->second.last > delivered_) {
        // What is left starts after it: the mark moves past the dropped records.
        delivered_ = oldest->second.last;
        mark_dirty_ = true;
    }
    return remove_segment(oldest);
}

Result<std::uint64_t> StoreFiles::append(std::span<const std::uint8_t> body) {
    if (body.size() > store::max_record_body)
        return fail(Errc::invalid_argument,
                    fmt::format("store: a record of {} bytes, more than the {} one may have",
                                body.size(), store::max_record_body));
    if (next_ > max_record_number)
        return fail(Errc::invalid_argument, "store: record numbers are used up");
    for (;;) {
        auto appended = append_once(body);
        // A full disk keeps the newest, as max_size does (gateway.md §6.2): the oldest segment
        // goes, and the record is tried again, while there is an older segment to give.
        if (appended || appended.error().code != Errc::no_space || segments_.size() < 2)
            return appended;
        const auto before = dropped_;
        if (auto dropped = drop_oldest(); !dropped) return Unexpected(dropped.error());
        dropped_full_ += dropped_ - before;
    }
}

Result<std::uint64_t> StoreFiles::append_once(std::span<const std::uint8_t> body) {
    const std::uint64_t size = store::record_header_bytes + body.size();
    if (writer_ < 0 || (segments_.rbegin()->second.bytes > 0 &&
                        segments_.rbegin()->second.bytes + size > segment_bytes_))
        if (auto started = start_segment(); !started) return Unexpected(started.error());
    while (segments_.size() > 1 && counts().bytes + size > max_size_)
        if (auto dropped = drop_oldest(); !dropped) return Unexpected(dropped.error());

    auto& segment = segments_.rbegin()->second;
    buffer_.clear();
    store::append_record(buffer_, next_, body);
    if (auto written = dir_->write(writer_, buffer_); !written) {
        // Nothing half written stays: the segment ends where it ended.
        if (!dir_->truncate(writer_, segment.bytes)) close_writer();
        return Unexpected(written.error());
    }
    segment.last = next_;
    ++segment.records;
    segment.bytes += size;
    data_dirty_ = true;
    return next_++;
}

Result<> StoreFiles::sync() {
    if (mark_dirty_) {
        if (auto marked = write_mark(); !marked) return marked;
        mark_dirty_ = false;
    }
    if (data_dirty_ && writer_ >= 0)
        if (auto synced = dir_->sync(writer_); !synced) return synced;
    data_dirty_ = false;
    if (dir_dirty_)
        if (auto synced = dir_->sync_names(); !synced) return synced;
    dir_dirty_ = false;
    return {};
}

Result<std::vector<StoredRecord>> StoreFiles::read_after(std::uint64_t after, std::size_t count,
                                                         std::size_t max_bytes) {
    std::vector<StoredRecord> records;
    std::size_t bytes = 0;
    for (const auto& [first, segment] : segments_) {
        if (segment.records == 0 || segment.last <= after) continue;
        if (!cached_ || cached_->first != first || cached_->bytes.size() != segment.bytes) {
            auto read = dir_->read(segment_name(first), segment.bytes);
            if (!read) return Unexpected(read.error());
            cached_.emplace(Cached{first, *std::move(read), {}});
            cached_->records = store::scan_segment(cached_->bytes).records;
        }
        const auto& in = cached_->records;
        auto it = std::ranges::upper_bound(in, std::max(after, first - 1), {},
                                           &store::RecordView::number);
        for (; it != in.end(); ++it) {
            if (records.size() == count ||
                (!records.empty() && bytes + it->body.size() > max_bytes))
                return records;
            records.push_back({it->number, {it->body.begin(), it->body.end()}});
            bytes += it->body.size();
        }
    }
    return records;
}

Result<> StoreFiles::deliver(std::uint64_t through) {
    through = std::min(through, next_ - 1);
    if (through <= delivered_) return {};
    delivered_ = through;
    for (auto it = segments_.begin(); it != segments_.end() && it->second.last <= delivered_;) {
        auto next = std::next(it);
        if (auto removed = remove_segment(it); !removed) return removed;
        it = next;
    }
    mark_dirty_ = true;
    return {};
}

Result<> StoreFiles::write_mark() {
    std::array<std::uint8_t, mark_bytes> mark{};
    endian::store_little_u64(mark.data(), delivered_);
    endian::store_little_u32(mark.data() + 8, crc32(std::span(mark).first(8)));
    const auto file = dir_->open_append(mark_temporary, true);
    if (!file) return Unexpected(file.error());
    // Its bytes reach the disk before its name does: a rename made durable first could leave
    // the mark empty after a power cut, and a damaged mark forwards the whole store again.
    auto written = dir_->write(*file, mark);
    if (written) written = dir_->sync(*file);
    dir_->close(*file);
    if (!written) return written;
    if (auto renamed = dir_->rename(mark_temporary, mark_name); !renamed) return renamed;
    dir_dirty_ = true;
    return {};
}

Result<> StoreFiles::save_bdseq(std::uint64_t next) {
    const auto text = fmt::format("{}\n", next);
    const auto file = dir_->open_append(bdseq_temporary, true);
    if (!file) return Unexpected(file.error());
    auto written = dir_->write(
        *file, std::span(reinterpret_cast<const std::uint8_t*>(text.data()), text.size()));
    dir_->close(*file);
    if (!written) return written;
    if (auto renamed = dir_->rename(bdseq_temporary, bdseq_name); !renamed) return renamed;
    dir_dirty_ = true;
    return {};
}

StoreCounts StoreFiles::counts() const {
    StoreCounts counts;
    for (const auto& [first, segment] : segments_) {
        counts.bytes += segment.bytes;
        counts.records += pending_in(segment);
    }
    counts.dropped = dropped_;
    counts.dropped_full = dropped_full_;
    return counts;
}

}  // namespace ioport::daemon
