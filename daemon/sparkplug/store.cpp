#include "daemon/sparkplug/store.hpp"

#include <utility>

#include <fmt/format.h>

namespace ioport::daemon {

Result<std::shared_ptr<SparkplugStore>> SparkplugStore::open(const asio::any_io_executor& loop,
                                                             const config::StoreSettings& settings,
                                                             Log& log) {
    auto files = StoreFiles::open(settings.path, settings.max_size);
    if (!files) return Unexpected(files.error());
    const auto& found = files->recovery();
    log.info({}, "Sparkplug store {}: {} record(s) to forward in {} segment(s){}", settings.path,
             found.records, found.segments,
             found.skipped_bytes == 0
                 ? std::string()
                 : fmt::format("; {} torn or corrupted byte(s) skipped, not replayed",
                               found.skipped_bytes));
    std::shared_ptr<SparkplugStore> store(
        new SparkplugStore(loop, settings, log, *std::move(files)));
    store->start_syncing();
    return store;
}

SparkplugStore::SparkplugStore(const asio::any_io_executor& loop, config::StoreSettings settings,
                               Log& log, StoreFiles files)
    : loop_(loop),
      settings_(std::move(settings)),
      log_(log),
      files_(std::move(files)),
      sync_timer_(loop) {
    const auto counts = files_.counts();
    stats_.bytes = counts.bytes;
    stats_.records = counts.records;
    delivered_ = files_.delivered();
}

SparkplugStore::~SparkplugStore() {
    sync_timer_.cancel();
    // The last sync's outcome is logged here, after the join: the log is the loop thread's.
    Result<> synced;
    asio::post(disk_, [this, &synced] { synced = files_.sync(); });
    disk_.join();
    if (!synced) log_.error({}, "{}", synced.error().message);
}

void SparkplugStore::failed(std::string_view key, const Error& error) {
    if (const auto held = errors_.admit(key, LogLimiter::Clock::now()))
        log_.error({}, "{}{}; records are being lost, live publishing goes on", error.message,
                   held_back(*held));
}

void SparkplugStore::full(std::uint64_t dropped) {
    const auto now_dropped = dropped - dropped_oldest_;
    dropped_oldest_ = dropped;
    held_full_ += now_dropped;
    if (!errors_.admit("full", LogLimiter::Clock::now())) return;
    log_.warn({}, "Sparkplug store {} is full ({} MiB): its {} oldest record(s) dropped",
              settings_.path, settings_.max_size >> 20, std::exchange(held_full_, 0));
}

template <class Job, class Then>
void SparkplugStore::on_disk(Job job, Then then) {
    asio::post(disk_, [this, weak = weak_from_this(), job = std::move(job),
                       then = std::move(then)]() mutable {
        auto result = job(files_);
        const auto counts = files_.counts();
        const auto delivered = files_.delivered();
        asio::post(loop_, [weak, then = std::move(then), result = std::move(result), counts,
                           delivered]() mutable {
            const auto self = weak.lock();
            if (!self) return;
            self->stats_.bytes = counts.bytes;
            self->stats_.records = counts.records;
            if (counts.dropped > self->dropped_oldest_) self->full(counts.dropped);
            self->stats_.dropped = counts.dropped + self->lost_;
            self->delivered_ = delivered;
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

}  // namespace ioport::daemon
