#include "link/port_reader.hpp"

#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <mutex>
#include <string>
#include <system_error>

namespace ioport {

// What the thread and the loop share. The loop's handlers hold it too, so that one that was
// already posted when the reader went away finds `attached` false and does nothing.
struct PortReader::Shared {
    asio::any_io_executor loop;
    std::function<void()> on_input;  // called on the loop only
    bool attached = true;            // loop only: false once the reader is destroyed

    std::mutex mutex;
    std::string queued;               // read, not yet taken
    std::string outgoing;             // given to send(), not yet taken by the tty
    std::size_t taken = 0;            // how much of `queued` the loop has taken
    std::uint64_t dropped = 0;        // beyond max_queued
    std::uint64_t generation = 0;     // discard() counts up: a read begun before is stale
    boost::system::error_code error;  // the port failed; nothing more is read
    bool notify_pending = false;      // a call of on_input is on its way to the loop

    // With the mutex held: tells the loop, once per batch of input.
    void notify_locked(const std::shared_ptr<Shared>& self) {
        if (notify_pending) return;
        notify_pending = true;
        asio::post(loop, [self] {
            {
                const std::lock_guard lock(self->mutex);
                self->notify_pending = false;
            }
            if (self->attached) self->on_input();
        });
    }
};

PortReader::PortReader(const asio::any_io_executor& loop, int fd, std::function<void()> on_input)
    : shared_(std::make_shared<Shared>()), fd_(fd), wake_fd_(::eventfd(0, EFD_CLOEXEC)) {
    shared_->loop = loop;
    shared_->on_input = std::move(on_input);
    if (wake_fd_ < 0)
        throw std::system_error(errno, std::generic_category(), "eventfd for the port's reader");
    try {
        thread_ = std::thread([this] { run(); });
    } catch (...) {
        ::close(wake_fd_);
        throw;
    }
}

PortReader::~PortReader() {
    shared_->attached = false;
    stopping_ = true;
    wake();
    thread_.join();
    ::close(wake_fd_);
}

void PortReader::wake() {
    // An eventfd takes a write of 8 bytes unless its counter would overflow, which writes of 1
    // between the thread's reads of it cannot make it do.
    const std::uint64_t one = 1;
    [[maybe_unused]] const auto written = ::write(wake_fd_, &one, sizeof one);
}

void PortReader::send(std::string_view bytes) {
    {
        const std::lock_guard lock(shared_->mutex);
        shared_->outgoing.append(bytes);
    }
    wake();
}

std::size_t PortReader::unsent() const {
    const std::lock_guard lock(shared_->mutex);
    return shared_->outgoing.size();
}

void PortReader::drop_unsent() {
    const std::lock_guard lock(shared_->mutex);
    shared_->outgoing.clear();
}

std::size_t PortReader::take(std::span<char> into) {
    const std::lock_guard lock(shared_->mutex);
    auto& s = *shared_;
    const auto n = std::min(into.size(), s.queued.size() - s.taken);
    std::memcpy(into.data(), s.queued.data() + s.taken, n);
    s.taken += n;
    if (s.taken == s.queued.size()) {
        s.queued.clear();
        s.taken = 0;
    } else if (s.taken >= max_queued) {  // a loop that never quite catches up: bounded still
        s.queued.erase(0, s.taken);
        s.taken = 0;
    }
    return n;
}

boost::system::error_code PortReader::error() const {
    const std::lock_guard lock(shared_->mutex);
    return shared_->error;
}

void PortReader::discard() {
    const std::lock_guard lock(shared_->mutex);
    shared_->queued.clear();
    shared_->taken = 0;
    ++shared_->generation;
}

std::uint64_t PortReader::bytes_dropped() const {
    const std::lock_guard lock(shared_->mutex);
    return shared_->dropped;
}

// Waits for input, room for what is to be sent, or the stop; reads what came and hands it over,
// sends what the tty takes; until stopped or the port fails. The waits have no timeout, as the
// loop's own epoll_wait has none: the link's timeouts are the loop's timers, and the stop comes
// through the eventfd.
void PortReader::run() {
    auto& s = *shared_;
    bool failed = false;
    while (!failed) {
        bool sending = false;
        {
            const std::lock_guard lock(s.mutex);
            sending = !s.outgoing.empty();
        }
        const auto events = static_cast<short>(POLLIN | (sending ? POLLOUT : 0));
        std::array<pollfd, 2> fds{{{fd_, events, 0}, {wake_fd_, POLLIN, 0}}};
        if (::poll(fds.data(), fds.size(), -1) < 0) {
            if (errno != EINTR) {
                fail(errno);
                failed = true;
            }
            continue;
        }
        if (fds[1].revents != 0) {
            std::uint64_t count = 0;
            [[maybe_unused]] const auto got = ::read(wake_fd_, &count, sizeof count);
            if (stopping_) return;
        }
        if ((fds[0].revents & POLLOUT) != 0) failed = !send_some();
        if ((fds[0].revents & (POLLIN | POLLHUP | POLLERR | POLLNVAL)) != 0 && !failed)
            failed = !read_some(fds[0].revents);
    }
    // Failed: nothing more is read or sent; wait for the stop.
    while (!stopping_) {
        pollfd stop{wake_fd_, POLLIN, 0};
        if (::poll(&stop, 1, -1) > 0) {
            std::uint64_t count = 0;
            [[maybe_unused]] const auto got = ::read(wake_fd_, &count, sizeof count);
        }
    }
}

void PortReader::fail(int err) {
    const std::lock_guard lock(shared_->mutex);
    shared_->error = {err, boost::system::system_category()};
    shared_->notify_locked(shared_);
}

bool PortReader::send_some() {
    const std::lock_guard lock(shared_->mutex);
    auto& outgoing = shared_->outgoing;
    const auto n = ::write(fd_, outgoing.data(), outgoing.size());
    if (n >= 0) {
        outgoing.erase(0, static_cast<std::size_t>(n));
        return true;
    }
    if (errno == EAGAIN || errno == EINTR) return true;
    shared_->error = {errno, boost::system::system_category()};
    shared_->notify_locked(shared_);
    return false;
}

// What came, once the poll said the tty is readable (or hung up: the read then says why).
bool PortReader::read_some(short revents) {
    auto& s = *shared_;
    std::uint64_t generation = 0;
    {
        const std::lock_guard lock(s.mutex);
        generation = s.generation;
    }
    std::array<char, 256> buffer{};
    const auto n = ::read(fd_, buffer.data(), buffer.size());
    if (n == 0) {  // end of file: the other side of a pty closed
        fail(EIO);
        return false;
    }
    if (n < 0) {
        if (errno == EINTR) return true;
        // Ready yet nothing to read, with a hang-up or an error: the port is gone, not waiting
        // to be read again (that would spin).
        if (errno == EAGAIN && (revents & (POLLHUP | POLLERR | POLLNVAL)) == 0) return true;
        fail(errno == EAGAIN ? EIO : errno);
        return false;
    }
    bytes_read_.fetch_add(static_cast<std::uint64_t>(n), std::memory_order_relaxed);
    const std::lock_guard lock(s.mutex);
    if (generation != s.generation) return true;  // flushed while it was being read
    const auto room = max_queued - (s.queued.size() - s.taken);
    const auto kept = std::min(room, static_cast<std::size_t>(n));
    s.queued.append(buffer.data(), kept);
    s.dropped += static_cast<std::size_t>(n) - kept;
    if (kept > 0) s.notify_locked(shared_);
    return true;
}

}  // namespace ioport
