// The Sparkplug store on the daemon's loop (gateway.md §6.2): DDATA kept while no session can
// publish it, read back for forwarding, deleted once the broker has it.
//
// The daemon's one thread other than the loop's is here: the disk's. Writing, syncing, reading
// and deleting the store's files (StoreFiles) block on the medium, and an SD card or eMMC can
// take seconds to sync; Boost 1.74's Asio has no asynchronous file I/O. So every file operation
// runs on one thread of its own, in the order it was asked for, and its result comes back to
// the loop as a completion. The thread touches nothing but the store's files and its own
// StoreFiles; the loop never waits for it: a disk that is slow or full costs records (counted,
// logged once a minute), never a poll or a Modbus answer. At most max_store_queue bytes wait for
// the disk; beyond that a record is dropped at once.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/log.hpp"
#include "daemon/sparkplug/store_files.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

inline constexpr std::size_t max_store_queue = std::size_t{1} << 20;
// Appended records are made durable this often: a power cut loses at most this much.
inline constexpr std::chrono::seconds store_sync_period{1};

struct StoreStats {
    std::uint64_t bytes = 0;      // on disk
    std::uint64_t records = 0;    // waiting to be forwarded
    std::uint64_t dropped = 0;    // lost: the oldest beyond max_size, or the disk did not take them
    std::uint64_t forwarded = 0;  // the broker has them
};

class SparkplugStore : public std::enable_shared_from_this<SparkplugStore> {
  public:
    // Opens the directory and recovers it (on the calling thread: at start-up or a reload,
    // before anything is appended); the journal says what was found.
    static Result<std::shared_ptr<SparkplugStore>> open(const asio::any_io_executor& loop,
                                                        const config::StoreSettings& settings,
                                                        Log& log);
    // The disk thread finishes what it was given, with a last sync, and ends.
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

    // The last record the broker is known to have; forwarding starts after it.
    std::uint64_t delivered() const { return delivered_; }
    // Records appended or on disk that were not delivered (those queued for the disk included).
    bool pending() const { return stats_.records > 0 || queued_ > 0; }
    StoreStats stats() const { return stats_; }
    const config::StoreSettings& settings() const { return settings_; }

  private:
    SparkplugStore(const asio::any_io_executor& loop, config::StoreSettings settings, Log& log,
                   StoreFiles files);
    void start_syncing();
    // Runs `job` on the disk thread, then `then` with its result and the counts on the loop.
    template <class Job, class Then>
    void on_disk(Job job, Then then);
    void failed(std::string_view key, const Error& error);
    void full(std::uint64_t dropped);

    asio::any_io_executor loop_;
    config::StoreSettings settings_;
    Log& log_;
    StoreFiles files_;  // the disk thread's alone, once open() returned
    asio::thread_pool disk_{1};
    asio::steady_timer sync_timer_;
    LogLimiter errors_;
    StoreStats stats_;
    std::uint64_t delivered_ = 0;
    std::size_t queued_ = 0;            // bytes of appends the disk has not done yet
    std::uint64_t lost_ = 0;            // appends the disk did not take, or that found it behind
    std::uint64_t dropped_oldest_ = 0;  // by StoreFiles, beyond max_size
    std::uint64_t held_full_ = 0;       // of those, not yet in a log line
    bool changed_since_sync_ = false;   // an append or a delivery
};

}  // namespace ioport::daemon
