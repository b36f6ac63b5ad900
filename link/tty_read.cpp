#include "link/tty_read.hpp"

#include <sys/ioctl.h>
#include <unistd.h>

#include <cerrno>

namespace ioport {

std::size_t read_queued(int fd, asio::mutable_buffer buffer, boost::system::error_code& ec,
                        bool readable) {
    ec = {};
    int queued = 0;
    // A failing FIONREAD (a hung-up tty) falls through to the read, which says why.
    if (!readable && ::ioctl(fd, FIONREAD, &queued) == 0 && queued <= 0) return 0;
    const auto n = ::read(fd, buffer.data(), buffer.size());
    if (n > 0) return static_cast<std::size_t>(n);
    if (n == 0)
        ec = asio::error::eof;
    else if (errno != EAGAIN && errno != EINTR)
        ec = {errno, boost::system::system_category()};
    return 0;
}

asio::awaitable<std::size_t> read_tty(asio::posix::stream_descriptor& tty,
                                      asio::mutable_buffer buffer, boost::system::error_code& ec) {
    std::size_t n = read_queued(tty.native_handle(), buffer, ec);
    while (n == 0 && !ec) {
        co_await tty.async_wait(asio::posix::stream_descriptor::wait_read,
                                asio::redirect_error(asio::use_awaitable, ec));
        if (!ec) n = read_queued(tty.native_handle(), buffer, ec, true);
    }
    co_return n;
}

}  // namespace ioport
