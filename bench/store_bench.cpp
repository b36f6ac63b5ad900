// The Sparkplug store's engine, chosen by measurement (issue 26, docs/store.md): the segment log
// ioportd uses (StoreFiles) against SQLite in WAL mode, under the same contract:
//   - every record is committed when appended (a crash of the process loses nothing written);
//   - once a second (every `rate` records) what was appended is made durable (a power cut loses
//     at most that second): StoreFiles::sync(), and for SQLite a WAL checkpoint with
//     synchronous=NORMAL, which syncs the WAL and the database;
//   - forwarding reads the records back oldest first, 20 at a time, and deletes them as the broker
//     has them.
// The records are real: stored DDATA of an acm3p channel (raw and value), as the node keeps them.
//
// Printed per engine: bytes handed to write() and bytes the kernel sent to the block device per
// record (/proc/self/io wchar, write_bytes), CPU per record appended and forwarded, and the time
// to open the store after the process that filled it was killed with SIGKILL.
//
// With --open-full SIZE instead: a store filled to SIZE (its max_size) with such records, and the
// time to open it, with the page cache warm and, where this process may drop it, cold: the
// figure behind the largest max_size the configuration allows (docs/store.md).
//
// Usage: ioportd-store-bench [--dir DIR] [--records N] [--rate R] [--open-full SIZE_MIB]
//   DIR: where the stores are made (default /var/tmp: a disk, not tmpfs, for write_bytes).
#include <signal.h>
#include <sqlite3.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "bench/process_io.hpp"
#include "daemon/sparkplug/store_files.hpp"
#include "protocol/sparkplug.hpp"

namespace {

namespace fs = std::filesystem;
using Bytes = std::vector<std::uint8_t>;
using Clock = std::chrono::steady_clock;

double cpu_seconds() {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    const auto seconds = [](const timeval& t) {
        return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_usec) / 1e6;
    };
    return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

// A stored DDATA of one acm3p channel that moved, as SparkplugNode::keep() makes it.
Bytes record(std::uint64_t n) {
    using namespace ioport::sparkplug;
    const std::uint64_t now = 1796183655123 + n * 50;
    const auto raw = static_cast<std::uint64_t>(n * 37 % 65536);
    return encode_stored(
        {"hub0.acm3p.0", Payload{now,
                                 std::nullopt,
                                 {Metric{"raw/0", std::nullopt, now, 6, Value(raw)},
                                  Metric{"value/0", std::nullopt, now, 9,
                                         Value(static_cast<float>(raw) / 65535.0F * 100.0F)}}}});
}

// One engine, behind the operations the node needs.
struct Engine {
    std::string name;
    std::function<void(const Bytes&)> append;
    std::function<void()> sync;
    // Up to 20 records after `after`; the number of the last one (after, when none).
    std::function<std::uint64_t(std::uint64_t after, std::size_t& count)> read;
    std::function<void(std::uint64_t through)> deliver;
};

void check(bool ok, const std::string& what) {
    if (ok) return;
    std::fprintf(stderr, "store-bench: %s\n", what.c_str());
    std::exit(1);
}

Engine segment_log(ioport::daemon::StoreFiles& files) {
    return {
        "segment log (ioportd)",
        [&files](const Bytes& body) { check(files.append(body).has_value(), "append"); },
        [&files] { check(files.sync().has_value(), "sync"); },
        [&files](std::uint64_t after, std::size_t& count) {
            const auto records = files.read_after(after, 20, std::size_t{1} << 20);
            check(records.has_value(), "read");
            count = records->size();
            return records->empty() ? after : records->back().number;
        },
        [&files](std::uint64_t through) { check(files.deliver(through).has_value(), "deliver"); }};
}

struct Sqlite {
    sqlite3* db = nullptr;
    sqlite3_stmt* insert = nullptr;
    sqlite3_stmt* select = nullptr;
    sqlite3_stmt* remove = nullptr;

    explicit Sqlite(const fs::path& file) {
        check(sqlite3_open(file.c_str(), &db) == SQLITE_OK, "sqlite open");
        exec("PRAGMA journal_mode=WAL");
        exec("PRAGMA synchronous=NORMAL");    // commits reach the WAL; syncs at checkpoints
        exec("PRAGMA wal_autocheckpoint=0");  // the checkpoint is ours, once a second
        exec("CREATE TABLE IF NOT EXISTS records(number INTEGER PRIMARY KEY, body BLOB)");
        prepare("INSERT INTO records(body) VALUES(?)", insert);
        prepare("SELECT number, body FROM records WHERE number > ? ORDER BY number LIMIT 20",
                select);
        prepare("DELETE FROM records WHERE number <= ?", remove);
    }
    ~Sqlite() {
        sqlite3_finalize(insert);
        sqlite3_finalize(select);
        sqlite3_finalize(remove);
        sqlite3_close(db);
    }
    Sqlite(const Sqlite&) = delete;
    Sqlite& operator=(const Sqlite&) = delete;
    void exec(const char* sql) {
        check(sqlite3_exec(db, sql, nullptr, nullptr, nullptr) == SQLITE_OK,
              fmt::format("{}: {}", sql, sqlite3_errmsg(db)));
    }
    void prepare(const char* sql, sqlite3_stmt*& statement) {
        check(sqlite3_prepare_v2(db, sql, -1, &statement, nullptr) == SQLITE_OK,
              fmt::format("{}: {}", sql, sqlite3_errmsg(db)));
    }
    std::uint64_t count() {
        sqlite3_stmt* statement = nullptr;
        prepare("SELECT count(*) FROM records", statement);
        check(sqlite3_step(statement) == SQLITE_ROW, "count");
        const auto n = static_cast<std::uint64_t>(sqlite3_column_int64(statement, 0));
        sqlite3_finalize(statement);
        return n;
    }
};

Engine sqlite_engine(Sqlite& s) {
    return {"SQLite 3.40, WAL",
            [&s](const Bytes& body) {
                sqlite3_bind_blob(s.insert, 1, body.data(), static_cast<int>(body.size()),
                                  SQLITE_STATIC);
                check(sqlite3_step(s.insert) == SQLITE_DONE, sqlite3_errmsg(s.db));
                sqlite3_reset(s.insert);
            },
            [&s] { s.exec("PRAGMA wal_checkpoint(PASSIVE)"); },
            [&s](std::uint64_t after, std::size_t& count) {
                sqlite3_bind_int64(s.select, 1, static_cast<sqlite3_int64>(after));
                count = 0;
                std::uint64_t last = after;
                while (sqlite3_step(s.select) == SQLITE_ROW) {
                    last = static_cast<std::uint64_t>(sqlite3_column_int64(s.select, 0));
                    ++count;
                }
                sqlite3_reset(s.select);
                return last;
            },
            [&s](std::uint64_t through) {
                sqlite3_bind_int64(s.remove, 1, static_cast<sqlite3_int64>(through));
                check(sqlite3_step(s.remove) == SQLITE_DONE, sqlite3_errmsg(s.db));
                sqlite3_reset(s.remove);
            }};
}

struct Figures {
    double wchar_per_record = 0;
    double disk_per_record = 0;
    double append_us = 0;   // CPU per record appended (syncs included)
    double forward_us = 0;  // CPU per record read and deleted
    std::uint64_t syncs = 0;
};

Figures run(const Engine& engine, std::uint64_t records, std::uint64_t rate) {
    std::vector<Bytes> bodies;
    for (std::uint64_t n = 0; n < records; ++n)
        bodies.push_back(record(n));
    Figures figures;
    const auto io_before = ioport::bench::process_io(getpid());
    const auto cpu_before = cpu_seconds();
    for (std::uint64_t n = 0; n < records; ++n) {
        engine.append(bodies[n]);
        if ((n + 1) % rate == 0) {
            engine.sync();
            ++figures.syncs;
        }
    }
    engine.sync();
    ++figures.syncs;
    const auto cpu_appended = cpu_seconds();
    const auto io_after = ioport::bench::process_io(getpid());
    std::uint64_t after = 0;
    std::uint64_t forwarded = 0;
    for (;;) {
        std::size_t count = 0;
        const auto last = engine.read(after, count);
        if (count == 0) break;
        engine.deliver(last);
        after = last;
        forwarded += count;
    }
    check(forwarded == records, fmt::format("forwarded {} of {}", forwarded, records));
    const auto cpu_forwarded = cpu_seconds();
    const auto n = static_cast<double>(records);
    figures.wchar_per_record = static_cast<double>(io_after.wchar - io_before.wchar) / n;
    figures.disk_per_record = static_cast<double>(io_after.write_bytes - io_before.write_bytes) / n;
    figures.append_us = (cpu_appended - cpu_before) / n * 1e6;
    figures.forward_us = (cpu_forwarded - cpu_appended) / n * 1e6;
    return figures;
}

// A child fills a store and is killed with SIGKILL; the milliseconds to open it again and count
// what it holds, and how many records it holds.
std::pair<double, std::uint64_t> recovery(const std::function<void()>& fill,
                                          const std::function<std::uint64_t()>& open_and_count) {
    const pid_t child = fork();
    if (child == 0) {
        fill();
        raise(SIGKILL);
    }
    int status = 0;
    waitpid(child, &status, 0);
    check(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL, "the child was not killed");
    const auto started = Clock::now();
    const auto count = open_and_count();
    return {std::chrono::duration<double, std::milli>(Clock::now() - started).count(), count};
}

// Fills a store to `max_size` and opens it again, warm and cold.
void open_full(const fs::path& dir, std::uint64_t max_size) {
    {
        auto files = ioport::daemon::StoreFiles::open(dir / "full", max_size);
        check(files.has_value(), "open the store to fill");
        for (std::uint64_t n = 0; files->counts().dropped == 0; ++n)
            check(files->append(record(n)).has_value(), "append");
        check(files->sync().has_value(), "sync");
    }
    const auto open = [&](const char* how) {
        const auto cpu = cpu_seconds();
        const auto started = Clock::now();
        auto files = ioport::daemon::StoreFiles::open(dir / "full", max_size);
        const auto took = std::chrono::duration<double>(Clock::now() - started).count();
        check(files.has_value(), "reopen the full store");
        const auto counts = files->counts();
        std::printf(
            "open a full store of %llu MiB (%llu records), %s: %.2f s, %.2f s of CPU, "
            "%.0f MiB/s\n",
            static_cast<unsigned long long>(max_size >> 20),
            static_cast<unsigned long long>(counts.records), how, took, cpu_seconds() - cpu,
            static_cast<double>(counts.bytes) / 1048576.0 / took);
    };
    open("page cache warm");
    ::sync();
    if (std::FILE* drop = std::fopen("/proc/sys/vm/drop_caches", "w")) {
        std::fputs("3\n", drop);
        std::fclose(drop);
        open("page cache dropped");
    }
}

}  // namespace

int main(int argc, char** argv) {
    fs::path base = "/var/tmp";
    std::uint64_t records = 50000;
    std::uint64_t rate = 200;
    std::uint64_t full_mib = 0;
    for (int i = 1; i + 1 < argc; i += 2) {
        const std::string option = argv[i];
        if (option == "--open-full")
            full_mib = std::stoull(argv[i + 1]);
        else if (option == "--dir")
            base = argv[i + 1];
        else if (option == "--records")
            records = std::stoull(argv[i + 1]);
        else if (option == "--rate")
            rate = std::stoull(argv[i + 1]);
    }
    const auto dir = base / fmt::format("ioportd-store-bench-{}", getpid());
    fs::create_directories(dir);
    if (full_mib > 0) {
        open_full(dir, full_mib << 20);
        fs::remove_all(dir);
        return 0;
    }
    const std::uint64_t max_size = std::uint64_t{1} << 30;
    const auto record_bytes = record(0).size();
    std::printf(
        "%llu records of %zu bytes (a stored DDATA of one acm3p channel), a sync every "
        "%llu records, in %s\n\n",
        static_cast<unsigned long long>(records), record_bytes,
        static_cast<unsigned long long>(rate), dir.c_str());
    std::printf("%-22s %12s %12s %12s %12s %8s %14s\n", "engine", "write()/rec", "disk/rec",
                "append CPU", "forward CPU", "syncs", "open after -9");

    const auto print = [&](const std::string& name, const Figures& f, double open_ms,
                           std::uint64_t found) {
        std::printf("%-22s %10.0f B %10.0f B %9.2f us %9.2f us %8llu %8.1f ms (%llu)\n",
                    name.c_str(), f.wchar_per_record, f.disk_per_record, f.append_us, f.forward_us,
                    static_cast<unsigned long long>(f.syncs), open_ms,
                    static_cast<unsigned long long>(found));
    };
    {
        auto files = ioport::daemon::StoreFiles::open(dir / "log", max_size);
        check(files.has_value(), "open the segment log");
        const auto figures = run(segment_log(*files), records, rate);
        const auto [open_ms, found] = recovery(
            [&] {
                auto again = ioport::daemon::StoreFiles::open(dir / "log-killed", max_size);
                for (std::uint64_t n = 0; n < records; ++n)
                    (void)again->append(record(n));
            },
            [&] {
                auto again = ioport::daemon::StoreFiles::open(dir / "log-killed", max_size);
                check(again.has_value(), "reopen the segment log");
                return again->counts().records;
            });
        print("segment log (ioportd)", figures, open_ms, found);
    }
    {
        Sqlite sqlite(dir / "store.db");
        const auto figures = run(sqlite_engine(sqlite), records, rate);
        const auto [open_ms, found] = recovery(
            [&] {
                Sqlite again(dir / "killed.db");
                auto engine = sqlite_engine(again);
                for (std::uint64_t n = 0; n < records; ++n)
                    engine.append(record(n));
            },
            [&] {
                Sqlite again(dir / "killed.db");
                return again.count();
            });
        print("SQLite 3.40, WAL", figures, open_ms, found);
    }
    fs::remove_all(dir);
    return 0;
}
