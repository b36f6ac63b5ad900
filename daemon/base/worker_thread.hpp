// A thread beside the loop's for work that blocks, each kind on its own so that one never waits
// behind the other (main owns them): the disk's (the Sparkplug store's file I/O: an SD card or
// eMMC can take seconds to sync, and Boost 1.74's Asio has no asynchronous file I/O) and the
// hashing of passwords (a bcrypt takes tens of milliseconds by design). Jobs run one at a time, in
// the order they were given, so that a store closed by a reload is synced and closed before its
// successor scans the same directory.
//
// Made on first use, so that a daemon without a store or passwords runs one thread. Destroyed
// after the gateway and before the io_context (main's order): it waits for what it was given
// (the last syncs), whose completions then stay queued on the stopped loop.
#pragma once

#include <optional>
#include <type_traits>
#include <utility>

#include "link/asio.hpp"

namespace ioport::daemon {

class WorkerThread {
  public:
    WorkerThread() = default;
    ~WorkerThread() {
        if (pool_) pool_->join();
    }
    WorkerThread(const WorkerThread&) = delete;
    WorkerThread& operator=(const WorkerThread&) = delete;

    template <class Job>
    void post(Job&& job) {
        if (!pool_) pool_.emplace(1);
        asio::post(*pool_, std::forward<Job>(job));
    }

    // Runs `job` here and completes with its result on `loop`: for a coroutine there to await.
    // Not a coroutine itself: g++ 12 freed a frame it did not own when this was one that
    // co_awaited the initiation (a unit test of the Authenticator crashed in free()).
    template <class Job, class Result = std::invoke_result_t<Job>>
    asio::awaitable<Result> run(const asio::any_io_executor& loop, Job job) {
        return asio::async_initiate<const asio::use_awaitable_t<>&, void(Result)>(
            [this, loop](auto handler, Job work) {
                this->post([loop, work = std::move(work), handler = std::move(handler)]() mutable {
                    asio::post(loop, [handler = std::move(handler), result = work()]() mutable {
                        std::move(handler)(std::move(result));
                    });
                });
            },
            asio::use_awaitable, std::move(job));
    }

  private:
    std::optional<asio::thread_pool> pool_;
};

}  // namespace ioport::daemon
