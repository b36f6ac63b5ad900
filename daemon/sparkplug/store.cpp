#include "daemon/sparkplug/store.hpp"

#include <type_traits>
#include <utility>

#include <fmt/format.h>

namespace ioport::daemon {

Result<std::shared_ptr<SparkplugStore>> SparkplugStore::open(const asio::any_io_executor& loop,
                                                             WorkerThread& disk,
                                                             const config::StoreSettings& settings,
                                                             Log& log,
                                                             std::function<void()> ready) {
    auto directory = DiskDirectory::open(settings.path);
    if (!directory) return Unexpected(directory.error());
    std::shared_ptr<SparkplugStore> store(new SparkplugStore(loop, disk, settings, log));
    // A few bytes, read on the loop as the directory was opened: the first CONNECT needs them.
    store->saved_bdseq_ = ioport::daemon::saved_bdseq(**directory);
    store->scan(*std::move(directory), std::move(ready));
    store->start_syncing();
    return store;
}

SparkplugStore::SparkplugStore(const asio::any_io_executor& loop, WorkerThread& disk,
                               config::StoreSettings settings, Log& log)
    : loop_(loop), disk_(disk), settings_(std::move(settings)), log_(log), sync_timer_(loop) {}

SparkplugStore::~SparkplugStore() {
    sync_timer_.cancel();
    {
        const std::lock_guard lock(shared_->mutex);
        shared_->closed = true;
    }
    // After every job given before: a reload's next store scans the same directory only then.
    disk_.post([shared = shared_] {
        if (shared->files) (void)shared->files->sync();  // its outcome: the next scan's line
        shared->files.reset();
    });
}

void SparkplugStore::scan(std::unique_ptr<StoreDirectory> directory, std::function<void()> ready) {
    disk_.post([shared = shared_, directory = std::move(directory), max_size = settings_.max_size,
                weak = weak_from_this(), loop = loop_, ready = std::move(ready)]() mutable {
        auto files = StoreFiles::open(std::move(directory), max_size);
        Result<StoreRecovery> found = files ? Result<StoreRecovery>(files->recovery())
                                            : Result<StoreRecovery>(Unexpected(files.error()));
        StoreCounts counts;
        std::uint64_t delivered = 0;
        if (files) {
            counts = files->counts();
            delivered = files->delivered();
            shared->files.emplace(*std::move(files));
        }
        const std::lock_guard lock(shared->mutex);
        if (shared->closed) return;
        asio::post(loop,
                   [weak, found = std::move(found), counts, delivered, ready = std::move(ready)] {
                       const auto self = weak.lock();
                       if (!self) return;
                       self->take(counts, delivered);
                       self->opened(found);
                       if (found) ready();
                   });
    });
}

void SparkplugStore::opened(const Result<StoreRecovery>& found) {
    if (!found) {
        log_.error({},
                   "{}: what changes while no broker takes it is lost until this is fixed and "
                   "the configuration reloaded",
                   found.error().message);
        return;
    }
    ready_ = true;
    log_.info({}, "Sparkplug store {}: {} record(s) to forward in {} segment(s){}", settings_.path,
              found->records, found->segments,
              found->skipped_bytes == 0
                  ? std::string()
                  : fmt::format("; {} torn or corrupted byte(s) skipped, not replayed",
                                found->skipped_bytes));
}

void SparkplugStore::failed(std::string_view key, const Error& error) {
    if (const auto held = errors_.admit(key, LogLimiter::Clock::now()))
        log_.error({}, "{}{}; records are being lost, live publishing goes on", error.message,
                   held_back(*held));
}

// The counts of the files, as the disk thread last saw them; what StoreFiles dropped is said
// once a minute, max_size and a full disk each in their own words.
void SparkplugStore::take(const StoreCounts& counts, std::uint64_t delivered) {
    stats_.bytes = counts.bytes;
    stats_.records = counts.records;
    stats_.dropped = counts.dropped + lost_;
    delivered_ = delivered;
    const auto size = counts.dropped - counts.dropped_full;
    held_size_ += size - std::exchange(dropped_size_, size);
    held_full_ += counts.dropped_full - std::exchange(dropped_full_, counts.dropped_full);
    const auto now = LogLimiter::Clock::now();
    if (held_size_ > 0 && errors_.admit("full", now))
        log_.warn({}, "Sparkplug store {} is full ({} MiB): its {} oldest record(s) dropped",
                  settings_.path, settings_.max_size >> 20, std::exchange(held_size_, 0));
    if (held_full_ > 0 && errors_.admit("disk full", now))
        log_.warn({},
                  "Sparkplug store {}: the disk is full: its {} oldest record(s) dropped to "
                  "keep the newest",
                  settings_.path, std::exchange(held_full_, 0));
}

template <class Job, class Then>
void SparkplugStore::on_disk(Job job, Then then) {
    disk_.post([shared = shared_, weak = weak_from_this(), loop = loop_, job = std::move(job),
                then = std::move(then)]() mutable {
        using Outcome = std::invoke_result_t<Job&, StoreFiles&>;
        // A store whose scan failed takes nothing: each call fails, counted by its completion.
        auto result =
            shared->files ? job(*shared->files) : Outcome(fail(Errc::io_error, "store: not open"));
        const auto counts = shared->files ? shared->files->counts() : StoreCounts{};
        const auto delivered = shared->files ? shared->files->delivered() : 0;
        const std::lock_guard lock(shared->mutex);
        if (shared->closed) return;
        asio::post(loop, [weak, then = std::move(then), result = std::move(result), counts,
                          delivered]() mutable {
            const auto self = weak.lock();
            if (!self) return;
            if (self->ready_) self->take(counts, delivered);
            then(*self, std::move(result));
        });
    });
}

void SparkplugStore::start_syncing() {
    sync_timer_.expires_after(store_sync_period);
    sync_timer_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        const auto self = weak.lock();
        if (ec || !self) return;
        if (std::exchange(self->changed_since_sync_, false))
            self->on_disk([](StoreFiles& files) { return files.sync(); },
                          [](SparkplugStore& store, const Result<>& synced) {
                              if (!synced) store.failed("sync", synced.error());
                          });
        self->start_syncing();
    });
}

bool SparkplugStore::append(std::vector<std::uint8_t> body) {
    if (queued_ + body.size() > max_store_queue) {
        ++lost_;
        ++stats_.dropped;
        failed("behind",
               Error{Errc::io_error, fmt::format("store {}: the disk is behind by {} bytes",
                                                 settings_.path, queued_)});
        return false;
    }
    const auto size = body.size();
    queued_ += size;
    changed_since_sync_ = true;
    on_disk([body = std::move(body)](StoreFiles& files) { return files.append(body); },
            [size](SparkplugStore& store, const Result<std::uint64_t>& appended) {
                store.queued_ -= size;
                if (appended) return;
                ++store.lost_;
                ++store.stats_.dropped;
                store.failed("append", appended.error());
            });
    return true;
}

void SparkplugStore::read_after(std::uint64_t after, std::size_t count,
                                std::function<void(std::vector<StoredRecord>)> done) {
    // A forward batch is a second's worth at most: bounded in memory whatever is on disk.
    constexpr std::size_t max_read_bytes = std::size_t{1} << 20;
    on_disk(
        [after, count](StoreFiles& files) {
            return files.read_after(after, count, max_read_bytes);
        },
        [done = std::move(done)](SparkplugStore& store, Result<std::vector<StoredRecord>> read) {
            if (!read) {
                store.failed("read", read.error());
                done({});
                return;
            }
            done(*std::move(read));
        });
}

void SparkplugStore::deliver(std::uint64_t through, std::uint64_t records) {
    stats_.forwarded += records;
    changed_since_sync_ = true;  // the mark is written at the next sync
    on_disk([through](StoreFiles& files) { return files.deliver(through); },
            [](SparkplugStore& store, const Result<>& delivered) {
                if (!delivered) store.failed("deliver", delivered.error());
            });
}

void SparkplugStore::save_bdseq(std::uint64_t next) {
    saved_bdseq_ = next;
    on_disk([next](StoreFiles& files) { return files.save_bdseq(next); },
            [](SparkplugStore& store, const Result<>& saved) {
                if (!saved) store.failed("bdseq", saved.error());
            });
}

}  // namespace ioport::daemon
