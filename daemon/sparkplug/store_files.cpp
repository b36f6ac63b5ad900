#include "daemon/sparkplug/store_files.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <system_error>
#include <utility>

#include <fmt/format.h>
#include <boost/crc.hpp>
#include <boost/endian/conversion.hpp>

#include "protocol/store_segment.hpp"

namespace ioport::daemon {
namespace {

namespace fs = std::filesystem;
namespace endian = boost::endian;

constexpr std::string_view segment_suffix = ".seg";
constexpr std::size_t name_digits = 20;
constexpr std::string_view mark_name = "delivered";
constexpr std::string_view mark_temporary = "delivered.tmp";
constexpr std::size_t mark_bytes = 12;

Unexpected<Error> io_fail(std::string_view what, const fs::path& path, int error) {
    return fail(Errc::io_error, fmt::format("store: cannot {} {}: {}", what, path.string(),
                                            std::generic_category().message(error)));
}

// "00000000000000004097.seg" -> 4097
std::optional<std::uint64_t> segment_number(const std::string& name) {
    if (name.size() != name_digits + segment_suffix.size() || !name.ends_with(segment_suffix))
        return std::nullopt;
    std::uint64_t number = 0;
    const auto [end, ec] = std::from_chars(name.data(), name.data() + name_digits, number);
    if (ec != std::errc{} || end != name.data() + name_digits) return std::nullopt;
    return number;
}

// At most `limit` bytes of a file.
Result<std::vector<std::uint8_t>> read_file(const fs::path& path, std::uint64_t limit) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return io_fail("open", path, errno);
    std::vector<std::uint8_t> bytes;
    std::array<std::uint8_t, std::size_t{64} << 10> chunk{};
    while (bytes.size() < limit) {
        const auto want = std::min<std::uint64_t>(chunk.size(), limit - bytes.size());
        const auto n = ::read(fd, chunk.data(), want);
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) {
            const int error = errno;
            ::close(fd);
            return io_fail("read", path, error);
        }
        if (n == 0) break;
        bytes.insert(bytes.end(), chunk.begin(), chunk.begin() + n);
    }
    ::close(fd);
    return bytes;
}

Result<> write_all(int fd, std::span<const std::uint8_t> bytes, const fs::path& path) {
    while (!bytes.empty()) {
        const auto n = ::write(fd, bytes.data(), bytes.size());
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) return io_fail("write", path, errno);
        bytes = bytes.subspan(static_cast<std::size_t>(n));
    }
    return {};
}

std::uint32_t crc32(std::span<const std::uint8_t> bytes) {
    boost::crc_32_type crc;
    crc.process_bytes(bytes.data(), bytes.size());
    return crc.checksum();
}

}  // namespace

std::uint64_t segment_bytes_for(std::uint64_t max_size) {
    return std::clamp(max_size / 16, min_segment_bytes, max_segment_bytes);
}

StoreFiles::StoreFiles(fs::path dir, std::uint64_t max_size)
    : dir_(std::move(dir)), max_size_(max_size), segment_bytes_(segment_bytes_for(max_size)) {}

StoreFiles::StoreFiles(StoreFiles&& other) noexcept
    : dir_(std::move(other.dir_)),
      max_size_(other.max_size_),
      segment_bytes_(other.segment_bytes_),
      segments_(std::move(other.segments_)),
      writer_(std::exchange(other.writer_, -1)),
      dir_fd_(std::exchange(other.dir_fd_, -1)),
      next_(other.next_),
      delivered_(other.delivered_),
      dropped_(other.dropped_),
      data_dirty_(other.data_dirty_),
      dir_dirty_(other.dir_dirty_),
      mark_dirty_(other.mark_dirty_),
      recovery_(other.recovery_),
      cached_(std::move(other.cached_)) {}

StoreFiles::~StoreFiles() {
    close_writer();
    if (dir_fd_ >= 0) ::close(dir_fd_);
}

Result<StoreFiles> StoreFiles::open(const fs::path& dir, std::uint64_t max_size) {
    StoreFiles files(dir, max_size);
    if (auto loaded = files.load(); !loaded) return Unexpected(loaded.error());
    return files;
}

fs::path StoreFiles::path_of(std::uint64_t first) const {
    return dir_ / fmt::format("{:0{}}{}", first, name_digits, segment_suffix);
}

std::uint64_t StoreFiles::pending_in(const Segment& segment) const {
    if (segment.records == 0 || delivered_ >= segment.last) return 0;
    if (delivered_ < segment.first) return segment.records;
    // Numbers within a segment are consecutive: append() numbers only what it wrote.
    return std::min(segment.records, segment.last - delivered_);
}

Result<> StoreFiles::load() {
    if (::mkdir(dir_.c_str(), 0750) != 0 && errno != EEXIST) return io_fail("create", dir_, errno);
    dir_fd_ = ::open(dir_.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dir_fd_ < 0) return io_fail("open the directory", dir_, errno);

    // The mark: a missing or damaged one means nothing is known delivered (duplicates, no loss).
    if (auto mark = read_file(dir_ / mark_name, mark_bytes);
        mark && mark->size() == mark_bytes &&
        endian::load_little_u32(mark->data() + 8) == crc32(std::span(*mark).first(8)))
        delivered_ = endian::load_little_u64(mark->data());

    std::vector<std::uint64_t> firsts;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir_, ec))
        if (const auto first = segment_number(entry.path().filename().string()))
            firsts.push_back(*first);
    if (ec) return io_fail("list", dir_, ec.value());
    std::ranges::sort(firsts);
    for (std::size_t i = 0; i < firsts.size(); ++i)
        if (auto loaded = load_segment(path_of(firsts[i]), firsts[i], i + 1 == firsts.size());
            !loaded)
            return loaded;

    std::uint64_t last = 0;
    for (const auto& [first, segment] : segments_)
        if (segment.records > 0) last = std::max(last, segment.last);
    next_ = std::max(last, delivered_) + 1;
    recovery_.segments = segments_.size();
    // Wholly delivered segments left by a crash before their deletion.
    for (auto it = segments_.begin(); it != segments_.end();) {
        auto next = std::next(it);
        if (it->second.records > 0 && it->second.last <= delivered_)
            if (auto removed = remove_segment(it); !removed) return removed;
        it = next;
    }
    recovery_.records = counts().records;
    if (!segments_.empty() && segments_.rbegin()->second.bytes < segment_bytes_) {
        const auto& newest = segments_.rbegin()->second;
        writer_ = ::open(path_of(newest.first).c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
        if (writer_ < 0) return io_fail("open", path_of(newest.first), errno);
    }
    return {};
}

Result<> StoreFiles::load_segment(const fs::path& file, std::uint64_t first, bool newest) {
    // A segment is at most segment_bytes_ and one more record; more is not this store's.
    const auto limit = segment_bytes_ + store::record_header_bytes + store::max_record_body;
    auto bytes = read_file(file, limit);
    if (!bytes) return Unexpected(bytes.error());
    std::uint64_t size = bytes->size();
    struct stat st {};
    if (::stat(file.c_str(), &st) == 0 && static_cast<std::uint64_t>(st.st_size) > size)
        recovery_.skipped_bytes += static_cast<std::uint64_t>(st.st_size) - size;

    const auto scan = store::scan_segment(*bytes);
    std::uint64_t previous = segments_.empty() ? 0 : segments_.rbegin()->second.last;
    Segment segment{first, first - 1, 0, 0};
    std::uint64_t good_bytes = 0;
    for (const auto& record : scan.records) {
        // Numbers below the name or not above the segment before: not this segment's.
        if (record.number < first || record.number <= previous) continue;
        previous = record.number;
        segment.last = record.number;
        ++segment.records;
        good_bytes += store::record_header_bytes + record.body.size();
    }
    recovery_.skipped_bytes += size - good_bytes;
    if (newest && scan.valid_end < size) {
        // A torn tail: appending resumes after the last good record.
        if (::truncate(file.c_str(), static_cast<off_t>(scan.valid_end)) != 0)
            return io_fail("truncate", file, errno);
        size = scan.valid_end;
        dir_dirty_ = true;
    }
    segment.bytes = size;
    if (segment.records == 0 && !newest) {
        if (::unlink(file.c_str()) != 0 && errno != ENOENT) return io_fail("remove", file, errno);
        dir_dirty_ = true;
        return {};
    }
    segments_[first] = segment;
    return {};
}

void StoreFiles::close_writer() {
    if (writer_ < 0) return;
    ::close(writer_);
    writer_ = -1;
}

Result<> StoreFiles::start_segment() {
    // What the old segment got is made durable before it is left.
    if (auto synced = sync(); !synced) return synced;
    close_writer();
    const auto file = path_of(next_);
    writer_ = ::open(file.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_TRUNC | O_CLOEXEC, 0640);
    if (writer_ < 0) return io_fail("create", file, errno);
    segments_[next_] = Segment{next_, next_ - 1, 0, 0};
    dir_dirty_ = true;
    return {};
}

Result<> StoreFiles::remove_segment(std::map<std::uint64_t, Segment>::iterator segment) {
    if (std::next(segment) == segments_.end()) close_writer();
    const auto file = path_of(segment->first);
    if (cached_ && cached_->first == segment->first) cached_.reset();
    segments_.erase(segment);
    dir_dirty_ = true;
    if (::unlink(file.c_str()) != 0 && errno != ENOENT) return io_fail("remove", file, errno);
    return {};
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
    const std::uint64_t size = store::record_header_bytes + body.size();
    if (writer_ < 0 || (segments_.rbegin()->second.bytes > 0 &&
                        segments_.rbegin()->second.bytes + size > segment_bytes_))
        if (auto started = start_segment(); !started) return Unexpected(started.error());
    while (segments_.size() > 1 && counts().bytes + size > max_size_)
        if (auto dropped = drop_oldest(); !dropped) return Unexpected(dropped.error());

    auto& segment = segments_.rbegin()->second;
    buffer_.clear();
    store::append_record(buffer_, next_, body);
    if (auto written = write_all(writer_, buffer_, path_of(segment.first)); !written) {
        // Nothing half written stays: the segment ends where it ended.
        if (::ftruncate(writer_, static_cast<off_t>(segment.bytes)) != 0) close_writer();
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
    if (data_dirty_ && writer_ >= 0) {
        if (::fdatasync(writer_) != 0)
            return io_fail("sync", path_of(segments_.rbegin()->first), errno);
    }
    data_dirty_ = false;
    if (dir_dirty_ && ::fsync(dir_fd_) != 0) return io_fail("sync the directory", dir_, errno);
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
            auto read = read_file(path_of(first), segment.bytes);
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
    const auto temporary = dir_ / mark_temporary;
    const int fd = ::open(temporary.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0640);
    if (fd < 0) return io_fail("create", temporary, errno);
    auto written = write_all(fd, mark, temporary);
    ::close(fd);
    if (!written) return written;
    if (::rename(temporary.c_str(), (dir_ / mark_name).c_str()) != 0)
        return io_fail("rename", temporary, errno);
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
    return counts;
}

}  // namespace ioport::daemon
