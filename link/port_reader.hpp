// A serial port's input, read on a thread of its own and taken by the loop.
//
// Linux hands a serial port's input to the tty through a kernel worker (the flip buffer), and a
// read or a poll of a tty whose input is still with that worker waits for it, non-blocking or
// not: read(), poll(), epoll_ctl() and epoll_wait() alike (n_tty_read and n_tty_poll call
// tty_buffer_flush_work). On a machine whose cores are busy that worker runs late, by tens of
// milliseconds and at times by seconds, and the one loop that also serves every Modbus and MQTT
// client must never wait on it. So the tty is read, and polled, here only, where such a wait
// stops nothing else; the loop takes what was read. The loop writes a request itself (a write
// does not wait for the worker); what the tty does not take at once (its output buffer full:
// the other side is not reading) is sent from here as room comes. The tty is never registered
// with the loop's epoll.
//
// The thread is started with the port's descriptor and stopped (and joined) before the
// descriptor is closed: the SerialLink that owns both makes sure of it.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string_view>
#include <thread>

#include <boost/system/error_code.hpp>

#include "link/asio.hpp"

namespace ioport {

class PortReader {
  public:
    // Input beyond this many bytes not yet taken is dropped: far more than any reply (the
    // longest is 40 bytes) and than the noise of the loop's slowest turn at 115200 baud.
    static constexpr std::size_t max_queued = 4096;

    // Starts reading `fd` (a tty opened non-blocking). `on_input` runs on `loop` when bytes or
    // an error have come since it last ran (never after this reader is destroyed).
    PortReader(const asio::any_io_executor& loop, int fd, std::function<void()> on_input);
    PortReader(const PortReader&) = delete;
    PortReader& operator=(const PortReader&) = delete;
    // Stops the thread and waits for it: at most the time a read in progress waits for the
    // kernel's worker.
    ~PortReader();

    // What has been read and not yet taken, oldest first, as much as `into` holds.
    std::size_t take(std::span<char> into);
    // Why the port failed (end of file, EIO when the adapter went away, a hang-up); reading has
    // stopped then. No error while the port is fine.
    boost::system::error_code error() const;
    // Forgets what was read and not yet taken, and what a read in progress returns, for the
    // link's flush of stale input (after tcflush() has dropped what the kernel held).
    void discard();
    // Sends `bytes` as the tty takes them, after whatever is still unsent.
    void send(std::string_view bytes);
    // Bytes given to send() that the tty has not taken yet.
    std::size_t unsent() const;
    // Forgets the bytes not yet sent (a request that could not go out in time).
    void drop_unsent();
    // Bytes read since the start, dropped ones included.
    std::uint64_t bytes_read() const { return bytes_read_.load(std::memory_order_relaxed); }
    // Bytes dropped because max_queued were waiting.
    std::uint64_t bytes_dropped() const;

  private:
    struct Shared;
    void run();
    void wake();
    // The thread's steps; false once the port has failed (the error is set for the loop).
    bool send_some();
    bool read_some(short revents);
    void fail(int err);  // sets the error the loop reads

    std::shared_ptr<Shared> shared_;
    int fd_;
    int wake_fd_;  // an eventfd: written when there is something to send, or to stop
    std::atomic<bool> stopping_{false};
    std::atomic<std::uint64_t> bytes_read_{0};
    std::thread thread_;
};

}  // namespace ioport
