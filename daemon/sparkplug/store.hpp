// The Sparkplug store on the daemon's loop (gateway.md §6.2): DDATA kept while no session can
// publish it, read back for forwarding, deleted once the broker has it.
//
// Every file operation (StoreFiles) runs on the daemon's disk thread (WorkerThread), in the order
// it was asked for, and its result comes back to the loop as a completion; the scan of a store
// at opening too, so that a large store costs neither start-up nor a reload any time on the
// loop, and closing does not wait for the last sync. The thread touches nothing but the store's
// files; the loop never waits for it: a disk that is slow or full costs records (counted, logged
// once a minute), never a poll or a Modbus answer. At most max_store_queue bytes wait for the
// disk; beyond that a record is dropped at once.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/base/log.hpp"
#include "daemon/base/worker_thread.hpp"
#include "daemon/sparkplug/store_files.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

inline constexpr std::size_t max_store_queue = std::size_t{1} << 20;
// Appended records are made durable this often: a power cut loses at most this much.
inline constexpr std::chrono::seconds store_sync_period{1};

struct StoreStats {
    std::uint64_t bytes = 0;      // on disk
    std::uint64_t records = 0;    // waiting to be forwarded
    std::uint64_t dropped = 0;    // lost: the oldest beyond max_size or for a full disk, or the
                                  // disk did not take them
    std::uint64_t forwarded = 0;  // the broker has them
};

class SparkplugStore : public std::enable_shared_from_this<SparkplugStore> {
  public:
    // Opens the directory now (created when missing; refused, as an error here, when another user
    // could write into it), then reads the mark and scans the segments on the disk thread; the
    // journal says what was found, and `ready` is called on the loop then. Appends made meanwhile
    // wait for the scan in the disk's queue.
    static Result<std::shared_ptr<SparkplugStore>> open(const asio::any_io_executor& loop,
                                                        WorkerThread& disk,
                                                        const config::StoreSettings& settings,
                                                        Log& log, std::function<void()> ready);
    // What was given to the disk is done there, then a last sync and the files closed; this
    // does not wait for it.
    ~SparkplugStore();
    SparkplugStore(const SparkplugStore&) = delete;
    SparkplugStore& operator=(const SparkplugStore&) = delete;

    // Queues a record for the disk; false, and counted as dropped, when the disk is behind.
    bool append(std::vector<std::uint8_t> body);
    // Up to `count` records after record `after`, oldest first, to `done` on the loop (empty on
    // an error, which is logged).
    void read_after(std::uint64_t after, std::size_t count,
                    std::function<void(std::vector<StoredRecord>)> done);
    // The broker has every record through `through`.
    void deliver(std::uint64_t through, std::uint64_t records);
    // The next bdSeq as the last run of the node left it in the directory, read at open().
    std::optional<std::uint64_t> saved_bdseq() const { return saved_bdseq_; }
    // Keeps `next` there for the next start (on the disk thread; a failure is logged).
    void save_bdseq(std::uint64_t next);

    // The scan is done: what the files hold is known.
    bool ready() const { return ready_; }
    // The last record the broker is known to have; forwarding starts after it.
    std::uint64_t delivered() const { return delivered_; }
    // Records appended or on disk that were not delivered (those queued for the disk included).
    bool pending() const { return stats_.records > 0 || queued_ > 0; }
    StoreStats stats() const { return stats_; }
    const config::StoreSettings& settings() const { return settings_; }

  private:
    // What the disk thread and the loop share: the files, the disk thread's alone once the scan
    // made them; and whether the store is still there to take the disk's completions.
    struct Shared {
        std::optional<StoreFiles> files;
        std::mutex mutex;     // held while a completion is posted, and while `closed` is set
        bool closed = false;  // the store is gone: nothing more is posted to the loop
    };
    SparkplugStore(const asio::any_io_executor& loop, WorkerThread& disk,
                   config::StoreSettings settings, Log& log);
    void scan(std::unique_ptr<StoreDirectory> directory, std::function<void()> ready);
    void opened(const Result<StoreRecovery>& found);
    void start_syncing();
    // Runs `job` on the disk thread, then `then` with its result and the counts on the loop.
    template <class Job, class Then>
    void on_disk(Job job, Then then);
    void take(const StoreCounts& counts, std::uint64_t delivered);
    void failed(std::string_view key, const Error& error);

    asio::any_io_executor loop_;
    WorkerThread& disk_;
    config::StoreSettings settings_;
    Log& log_;
    std::shared_ptr<Shared> shared_ = std::make_shared<Shared>();
    asio::steady_timer sync_timer_;
    LogLimiter errors_;
    StoreStats stats_;
    std::optional<std::uint64_t> saved_bdseq_;
    bool ready_ = false;
    std::uint64_t delivered_ = 0;
    std::size_t queued_ = 0;          // bytes of appends the disk has not done yet
    std::uint64_t lost_ = 0;          // appends the disk did not take, or that found it behind
    std::uint64_t dropped_full_ = 0;  // by StoreFiles, the oldest for a full disk
    std::uint64_t dropped_size_ = 0;  // by StoreFiles, the oldest beyond max_size
    std::uint64_t held_full_ = 0;     // of those, not yet in a log line
    std::uint64_t held_size_ = 0;
    bool changed_since_sync_ = false;  // an append or a delivery
};

}  // namespace ioport::daemon
