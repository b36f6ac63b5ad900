// A power cut at every point of the Sparkplug store (issue 42; docs/store.md, "What a power cut
// can do"). After the manner of SQLite's crash-test VFS and of ALICE and CrashMonkey: a scripted
// workload runs StoreFiles on a file system in memory (SimulatedDisk) that, before each operation
// that changes anything, builds every file system a power cut there could leave, opens the store
// on each, and checks what the store promises:
//  - every record appended before a sync() that returned is forwarded, unless the broker had it
//    or max_size dropped it (counted);
//  - nothing is forwarded that was never appended (its number and body are the appended ones),
//    and in order;
//  - the mark a sync() wrote stays (no replay of what the broker acknowledged before it);
//  - the open reads no byte twice, and the store goes on: a record appended after it is the next
//    number and is there at the next open.
//
// What a power cut leaves, per file and per name (the weakest POSIX model, no ext4 favours):
//  - a file's bytes as of its last fdatasync stay; what was written since is gone, all there, or
//    there up to any sector (512 B) boundary; and, a sample, the new size with none or all but
//    the last sector of the new data (the rest reads zeros: the size reached the disk, the data
//    did not). A file cut shorter (ftruncate) and not synced may show its old bytes past each
//    boundary.
//  - names made, renamed and removed since the directory's last fsync reached the disk in order,
//    up to any of them (a journal commits metadata in order).
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "daemon/sparkplug/store_files.hpp"

// A namespace of its own: the unit tests are built as one unit (CMAKE_UNITY_BUILD).
namespace ioport::daemon::store_crash {
namespace {

using Bytes = std::vector<std::uint8_t>;
constexpr std::size_t sector = 512;

// A directory in memory. Each file is an inode with its bytes now and as last synced; names map
// to inodes, now and as last synced, with each change of names since. Within a generation (from
// creation or a cut to fewer bytes) a file only grows, so (generation, length) names its bytes.
class SimulatedDisk final : public StoreDirectory {
  public:
    struct Inode {
        Bytes now;
        Bytes synced;
        std::uint64_t generation = 0;
        std::uint64_t synced_generation = 0;
    };
    using Names = std::map<std::string, std::size_t, std::less<>>;  // name → inode

    // Called before each operation that changes anything, with what it is.
    std::function<void(const std::string& operation)> on_change;
    std::uint64_t bytes_read = 0;

    // A disk holding `files`, to open the store on after a cut. No cut is made on it, so its
    // files' synced bytes are left empty (a copy of each saved).
    static std::unique_ptr<SimulatedDisk> holding(std::map<std::string, Bytes> files) {
        auto disk = std::make_unique<SimulatedDisk>();
        for (auto& [name, bytes] : files) {
            const auto inode = disk->make_inode();
            disk->inodes_[inode].now = std::move(bytes);
            disk->names_[name] = inode;
        }
        return disk;
    }

    // What each file holds now, as at a clean stop.
    std::map<std::string, Bytes> files() && {
        std::map<std::string, Bytes> out;
        for (const auto& [name, inode] : names_)
            out[name] = std::move(inodes_[inode].now);
        return out;
    }

    const std::vector<Inode>& inodes() const { return inodes_; }
    // The names as the directory's last fsync left them, then after each change since.
    std::vector<const Names*> names_after_cut() const {
        std::vector<const Names*> out{&synced_names_};
        for (const auto& names : changed_names_)
            out.push_back(&names);
        return out;
    }

    Result<std::vector<std::string>> names() override {
        std::vector<std::string> out;
        for (const auto& [name, inode] : names_)
            out.push_back(name);
        return out;
    }
    Result<Bytes> read(std::string_view name, std::uint64_t limit) override {
        const auto found = names_.find(name);
        if (found == names_.end()) return missing(name);
        const auto& bytes = inodes_[found->second].now;
        const auto n = std::min<std::uint64_t>(limit, bytes.size());
        bytes_read += n;
        return Bytes(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(n));
    }
    Result<std::uint64_t> size(std::string_view name) override {
        const auto found = names_.find(name);
        if (found == names_.end()) return missing(name);
        return inodes_[found->second].now.size();
    }
    Result<File> open_append(std::string_view name, bool create) override {
        if (create) {
            if (auto removed = remove(name); !removed) return Unexpected(removed.error());
            change(fmt::format("create {}", name));
            names_[std::string(name)] = make_inode();
            changed_names_.push_back(names_);
        }
        const auto found = names_.find(name);
        if (found == names_.end()) return missing(name);
        open_[next_file_] = found->second;
        return next_file_++;
    }
    Result<> write(File file, std::span<const std::uint8_t> bytes) override {
        auto& inode = inodes_[open_.at(file)];
        change(fmt::format("write {} B at {}", bytes.size(), inode.now.size()));
        inode.now.insert(inode.now.end(), bytes.begin(), bytes.end());
        return {};
    }
    Result<> truncate(File file, std::uint64_t size) override {
        auto& inode = inodes_[open_.at(file)];
        change(fmt::format("truncate {} B to {}", inode.now.size(), size));
        if (size < inode.now.size()) inode.generation = next_generation_++;
        inode.now.resize(size);
        return {};
    }
    Result<> sync(File file) override {
        auto& inode = inodes_[open_.at(file)];
        change("fdatasync");
        inode.synced = inode.now;
        inode.synced_generation = inode.generation;
        return {};
    }
    void close(File file) override { open_.erase(file); }
    Result<> rename(std::string_view from, std::string_view to) override {
        const auto found = names_.find(from);
        if (found == names_.end()) return missing(from);
        change(fmt::format("rename {} {}", from, to));
        const auto inode = found->second;
        names_.erase(found);
        names_[std::string(to)] = inode;
        changed_names_.push_back(names_);
        return {};
    }
    Result<> remove(std::string_view name) override {
        const auto found = names_.find(name);
        if (found == names_.end()) return {};
        change(fmt::format("remove {}", name));
        names_.erase(found);
        changed_names_.push_back(names_);
        return {};
    }
    Result<> sync_names() override {
        change("fsync the directory");
        synced_names_ = names_;
        changed_names_.clear();
        return {};
    }
    const std::filesystem::path& path() const override { return path_; }

  private:
    static Unexpected<Error> missing(std::string_view name) {
        return fail(Errc::io_error, fmt::format("store: no file {}", name));
    }
    std::size_t make_inode() {
        const auto generation = next_generation_++;
        inodes_.push_back({{}, {}, generation, generation});
        return inodes_.size() - 1;
    }
    void change(const std::string& operation) {
        if (on_change) on_change(operation);
    }

    std::vector<Inode> inodes_;
    Names names_;
    Names synced_names_;
    std::vector<Names> changed_names_;  // after each change of names since the directory's fsync
    std::map<File, std::size_t> open_;
    File next_file_ = 3;
    std::uint64_t next_generation_ = 1;
    std::filesystem::path path_ = "/simulated";
};

// What a power cut may leave of one file: its first `keep` bytes as now, then either its synced
// bytes beyond that (`old_tail`) or `zeros` zero bytes.
struct Leftover {
    std::size_t keep = 0;
    std::size_t zeros = 0;
    bool old_tail = false;
};

std::vector<Leftover> leftovers(const SimulatedDisk::Inode& inode) {
    const auto now = inode.now.size();
    const auto synced = inode.synced.size();
    if (inode.generation == inode.synced_generation) {
        // Grown since the sync (or unchanged): the synced bytes are a prefix of today's.
        std::vector<Leftover> out{{synced, 0, false}};
        if (now == synced) return out;
        for (auto at = (synced / sector + 1) * sector; at < now; at += sector)
            out.push_back({at, 0, false});
        // The size reached the disk and none or all but the last sector of the data did: a
        // sample of these, as each would be a new file system at every write.
        const auto last = out.back().keep;  // the last boundary before `now`, or `synced`
        out.push_back({synced, now - synced, false});
        if (last != synced) out.push_back({last, now - last, false});
        out.push_back({now, 0, false});
        return out;
    }
    // Cut since the sync: the new bytes up to each boundary, the old ones beyond.
    std::vector<Leftover> out{{0, 0, true}, {now, 0, false}};
    for (std::size_t at = sector; at < now; at += sector)
        out.push_back({at, 0, true});
    return out;
}

// The bytes a leftover names, and a key that is the same exactly when the bytes are.
Bytes bytes_of(const SimulatedDisk::Inode& inode, const Leftover& left) {
    Bytes out(inode.now.begin(), inode.now.begin() + static_cast<std::ptrdiff_t>(left.keep));
    if (left.old_tail && inode.synced.size() > left.keep)
        out.insert(out.end(), inode.synced.begin() + static_cast<std::ptrdiff_t>(left.keep),
                   inode.synced.end());
    out.resize(out.size() + left.zeros);
    return out;
}

std::string key_of(const SimulatedDisk::Inode& inode, const Leftover& left) {
    if (left.old_tail && inode.synced.size() > left.keep)
        return fmt::format("g{}:{}+g{}:{}", inode.generation, left.keep, inode.synced_generation,
                           inode.synced.size());
    return fmt::format("g{}:{}:{}", inode.generation, left.keep, left.zeros);
}

constexpr std::uint64_t max_size = std::uint64_t{128} << 10;  // two segments of 64 KiB

// Record n's body: its size (16 to 1,515 bytes) and bytes follow from n, so any record read
// back can be checked.
std::size_t body_size(std::uint64_t n) {
    return 16 + (n * 7919) % 1500;
}
std::uint8_t body_byte(std::uint64_t n, std::size_t i) {
    return static_cast<std::uint8_t>(n * 131 + i);
}
Bytes body_of(std::uint64_t n) {
    Bytes out(body_size(n));
    for (std::size_t i = 0; i < out.size(); ++i)
        out[i] = body_byte(n, i);
    return out;
}
// Whether `body` is record n's, without making one: this runs for every record of every open.
bool is_body_of(std::uint64_t n, std::span<const std::uint8_t> body) {
    if (body.size() != body_size(n)) return false;
    const auto* byte = body.data();
    for (std::size_t i = 0; i < body.size(); ++i)
        if (byte[i] != body_byte(n, i)) return false;
    return true;
}
const Bytes resumed_body{'a', 'f', 't', 'e', 'r'};

// What opening the store on one file system found; the same at every cut that can leave it.
struct Reopened {
    std::string failed;  // the open's error
    std::uint64_t delivered = 0;
    std::vector<std::uint64_t> numbers;  // forwarded, in the order read
    std::uint64_t wrong_bodies = 0;
    std::uint64_t counted = 0;  // counts().records
    std::uint64_t bytes_read = 0;
    std::uint64_t bytes_present = 0;
    std::string resumed;  // what went wrong appending after the open, if anything
};

std::vector<std::uint64_t> read_all(StoreFiles& files, std::uint64_t& wrong_bodies,
                                    std::string& failed) {
    std::vector<std::uint64_t> numbers;
    const auto records = files.read_after(files.delivered(), SIZE_MAX, SIZE_MAX);
    if (!records) {
        failed = records.error().message;
        return numbers;
    }
    for (const auto& record : *records) {
        numbers.push_back(record.number);
        if (!is_body_of(record.number, record.body) && record.body != resumed_body) ++wrong_bodies;
    }
    return numbers;
}

Reopened reopen(std::map<std::string, Bytes> files) {
    Reopened out;
    for (const auto& [name, bytes] : files)
        out.bytes_present += bytes.size();
    auto owned = SimulatedDisk::holding(std::move(files));
    auto& disk = *owned;
    auto opened = StoreFiles::open(std::move(owned), max_size);
    if (!opened) {
        out.failed = opened.error().message;
        return out;
    }
    out.bytes_read = disk.bytes_read;
    out.delivered = opened->delivered();
    out.counted = opened->counts().records;
    out.numbers = read_all(*opened, out.wrong_bodies, out.failed);

    // The store goes on after the cut: the next record is numbered after all it holds, and
    // it is there, after them, at the next start.
    const auto appended = opened->append(resumed_body);
    if (!appended || !opened->sync()) {
        out.resumed = "appending after the open failed";
        return out;
    }
    const auto last = out.numbers.empty() ? out.delivered : out.numbers.back();
    if (*appended <= last) {
        out.resumed = fmt::format("numbered {} after {}", *appended, last);
        return out;
    }
    // Less what max_size dropped to make room for it.
    std::vector<std::uint64_t> expected;
    for (const auto n : out.numbers)
        if (n > opened->delivered()) expected.push_back(n);
    expected.push_back(*appended);
    std::uint64_t wrong = 0;
    if (const auto numbers = read_all(*opened, wrong, out.resumed);
        numbers != expected || wrong != 0) {
        out.resumed = fmt::format("{} record(s) forwarded after it, not the {} expected",
                                  numbers.size(), expected.size());
        return out;
    }
    auto again = StoreFiles::open(SimulatedDisk::holding(std::move(disk).files()), max_size);
    const auto numbers =
        again ? read_all(*again, wrong, out.resumed) : std::vector<std::uint64_t>{};
    if (!again || numbers != expected || wrong != 0)
        out.resumed = fmt::format("the next open forwards {} record(s), not the {} expected",
                                  numbers.size(), expected.size());
    return out;
}

// What the workload has been promised at a point of its run.
struct Promised {
    std::uint64_t started = 0;  // the highest number an append was asked for
    std::uint64_t synced = 0;   // records through this one were appended before a sync returned
    std::uint64_t marked = 0;   // the mark that sync wrote
};

class CrashCheck {
  public:
    // Every file system a cut before `operation` can leave, checked against `promised`; `gone`:
    // records through this one the broker has or max_size dropped.
    void cut(const SimulatedDisk& disk, const std::string& operation, const Promised& promised,
             std::uint64_t gone) {
        ++cuts_;
        for (const auto* names : disk.names_after_cut()) {
            // The files of these names whose bytes a cut may change, and how.
            std::vector<std::pair<std::string, std::size_t>> files(names->begin(), names->end());
            std::vector<std::vector<Leftover>> choices;
            for (const auto& [name, inode] : files)
                choices.push_back(leftovers(disk.inodes()[inode]));
            std::vector<std::size_t> pick(files.size(), 0);
            for (;;) {
                check(disk, files, choices, pick, operation, promised, gone);
                std::size_t i = 0;
                while (i < pick.size() && ++pick[i] == choices[i].size())
                    pick[i++] = 0;
                if (i == pick.size()) break;
            }
        }
    }

    std::uint64_t cuts() const { return cuts_; }
    std::uint64_t states() const { return states_; }
    std::uint64_t distinct() const { return seen_.size(); }
    const std::map<std::string, std::pair<std::uint64_t, std::string>>& findings() const {
        return findings_;
    }

  private:
    void check(const SimulatedDisk& disk,
               const std::vector<std::pair<std::string, std::size_t>>& files,
               const std::vector<std::vector<Leftover>>& choices,
               const std::vector<std::size_t>& pick, const std::string& operation,
               const Promised& promised, std::uint64_t gone) {
        ++states_;
        std::string key;
        for (std::size_t i = 0; i < files.size(); ++i)
            key += fmt::format("{}={} ", files[i].first,
                               key_of(disk.inodes()[files[i].second], choices[i][pick[i]]));
        auto found = seen_.find(key);
        if (found == seen_.end()) {
            std::map<std::string, Bytes> state;
            for (std::size_t i = 0; i < files.size(); ++i)
                state[files[i].first] =
                    bytes_of(disk.inodes()[files[i].second], choices[i][pick[i]]);
            found = seen_.emplace(key, reopen(std::move(state))).first;
        }
        const auto& got = found->second;
        const auto where = [&] {
            return fmt::format("cut {} before \"{}\", files {}", cuts_, operation, key);
        };
        if (!got.failed.empty()) find("the open fails", where() + ": " + got.failed);
        // Every record synced and not gone is forwarded.
        auto at = std::ranges::lower_bound(got.numbers, gone + 1);
        for (auto n = gone + 1; n <= promised.synced; ++n, ++at)
            if (at == got.numbers.end() || *at != n) {
                find("a synced record is lost", fmt::format("{}: record {}", where(), n));
                break;
            }
        if (std::ranges::adjacent_find(got.numbers, std::greater_equal<>()) != got.numbers.end())
            find("out of order", where());
        if (got.wrong_bodies > 0 || (!got.numbers.empty() && got.numbers.back() > promised.started))
            find("a record never appended is forwarded", where());
        if (got.delivered < promised.marked)
            find("the mark a sync wrote is lost",
                 fmt::format("{}: mark {}, not {}", where(), got.delivered, promised.marked));
        if (got.counted != got.numbers.size())
            find("counts() disagrees with what is forwarded",
                 fmt::format("{}: {} counted, {} forwarded", where(), got.counted,
                             got.numbers.size()));
        if (got.bytes_read > got.bytes_present)
            find("the open reads more than is there",
                 fmt::format("{}: {} B read of {} B", where(), got.bytes_read, got.bytes_present));
        if (!got.resumed.empty()) find("the store does not go on", where() + ": " + got.resumed);
    }

    void find(const std::string& what, std::string example) {
        auto& [count, first] = findings_[what];
        if (count++ == 0) first = std::move(example);
    }

    std::uint64_t cuts_ = 0;
    std::uint64_t states_ = 0;
    std::unordered_map<std::string, Reopened> seen_;
    std::map<std::string, std::pair<std::uint64_t, std::string>> findings_;  // first example
};

// The store's life in three acts, cut before each of its operations: a broker taking each
// second's records; a broker away while segments fill, roll over and max_size drops the
// oldest; the broker back, taking the backlog while new records come.
TEST(StoreCrash, EveryCutPointLeavesWhatWasPromised) {
    const auto start = std::chrono::steady_clock::now();
    auto owned = std::make_unique<SimulatedDisk>();
    auto& disk = *owned;
    CrashCheck crash;
    Promised promised;
    StoreFiles* store = nullptr;
    disk.on_change = [&](const std::string& operation) {
        crash.cut(disk, operation, promised, store != nullptr ? store->delivered() : 0);
    };
    auto opened = StoreFiles::open(std::move(owned), max_size);
    ASSERT_TRUE(opened) << opened.error().message;
    auto& files = *opened;
    store = &files;

    std::uint64_t next = 1;
    const auto append = [&] {
        promised.started = next;
        const auto appended = files.append(body_of(next));
        ASSERT_TRUE(appended) << appended.error().message;
        ASSERT_EQ(*appended, next++);
    };
    const auto sync = [&] {  // the once-a-second sync
        const auto through = next - 1;
        const auto mark = files.delivered();
        ASSERT_TRUE(files.sync());
        promised.synced = through;
        promised.marked = mark;
    };
    const auto forward = [&](std::size_t count) {  // the broker takes a batch
        const auto records = files.read_after(files.delivered(), count, SIZE_MAX);
        ASSERT_TRUE(records) << records.error().message;
        if (!records->empty()) {
            ASSERT_TRUE(files.deliver(records->back().number));
        }
    };

    for (int second = 0; second < 100; ++second) {
        for (int i = 0; i < 6; ++i)
            append();
        forward(SIZE_MAX);
        sync();
    }
    for (int second = 0; second < 26; ++second) {
        for (int i = 0; i < 10; ++i)
            append();
        sync();
    }
    EXPECT_GT(files.counts().dropped, 0U) << "max_size never dropped the oldest";
    for (int second = 0; second < 10; ++second) {
        forward(20);
        for (int i = 0; i < 3; ++i)
            append();
        sync();
    }
    forward(SIZE_MAX);
    sync();
    EXPECT_EQ(files.counts().records, 0U);
    disk.on_change("(the end)");

    const auto took = std::chrono::duration<double>(std::chrono::steady_clock::now() - start);
    fmt::print("{} cut points, {} file systems checked ({} different), {:.2f} s\n", crash.cuts(),
               crash.states(), crash.distinct(), took.count());
    EXPECT_GE(crash.cuts(), 1000U);
    for (const auto& [what, found] : crash.findings())
        ADD_FAILURE() << what << ": " << found.first << " time(s), first at " << found.second;
}

}  // namespace
}  // namespace ioport::daemon::store_crash
