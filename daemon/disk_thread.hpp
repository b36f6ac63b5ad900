// The daemon's one thread beside the loop's: file I/O that blocks on the medium (the Sparkplug
// store's: an SD card or eMMC can take seconds to sync, and Boost 1.74's Asio has no
// asynchronous file I/O). Jobs run one at a time, in the order they were given, so that a store
// closed by a reload is synced and closed before its successor scans the same directory.
//
// Made on first use, so that a daemon without a store runs one thread. Destroyed after the
// gateway and before the io_context (main's order): it waits for what it was given (the last
// syncs), whose completions then stay queued on the stopped loop.
#pragma once

#include <optional>
#include <utility>

#include "link/asio.hpp"

namespace ioport::daemon {

class DiskThread {
  public:
    DiskThread() = default;
    ~DiskThread() {
        if (pool_) pool_->join();
    }
    DiskThread(const DiskThread&) = delete;
    DiskThread& operator=(const DiskThread&) = delete;

    template <class Job>
    void post(Job&& job) {
        if (!pool_) pool_.emplace(1);
        asio::post(*pool_, std::forward<Job>(job));
    }

  private:
    std::optional<asio::thread_pool> pool_;
};

}  // namespace ioport::daemon
