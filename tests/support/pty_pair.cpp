#include "tests/support/pty_pair.hpp"

#include <fcntl.h>
#include <stdlib.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <array>
#include <thread>

namespace ioport::test {

PtyDevice::PtyDevice(asio::io_context& io, char terminator)
    : io_(io), terminator_(terminator), master_(io) {
    const int master = ::posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC | O_NONBLOCK);
    std::array<char, 128> name{};
    if (master < 0 || ::grantpt(master) != 0 || ::unlockpt(master) != 0 ||
        ::ptsname_r(master, name.data(), name.size()) != 0) {
        ADD_FAILURE() << "cannot create a pty";
        return;
    }
    path_ = name.data();
    slave_fd_ = ::open(path_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
    termios tio{};
    ::tcgetattr(slave_fd_, &tio);
    ::cfmakeraw(&tio);
    ::tcsetattr(slave_fd_, TCSANOW, &tio);
    master_.assign(master);
}

PtyDevice::~PtyDevice() {
    hang_up();
}

void PtyDevice::serve(Script script) {
    script_ = std::move(script);
    asio::co_spawn(io_, read_requests(), asio::detached);
}

void PtyDevice::send(std::string_view bytes) {
    boost::system::error_code ec;
    asio::write(master_, asio::buffer(bytes.data(), bytes.size()), ec);
    EXPECT_FALSE(ec) << ec.message();
}

void PtyDevice::hang_up() {
    boost::system::error_code ignored;
    master_.close(ignored);
    if (slave_fd_ >= 0) ::close(slave_fd_);
    slave_fd_ = -1;
}

asio::awaitable<void> PtyDevice::read_requests() {
    std::array<char, 256> buffer{};
    std::string line;
    for (;;) {
        boost::system::error_code ec;
        const auto n = co_await master_.async_read_some(
            asio::buffer(buffer), asio::redirect_error(asio::use_awaitable, ec));
        if (ec) co_return;
        for (std::size_t i = 0; i < n; ++i) {
            const bool one_byte_requests = terminator_ == '\0';
            if (!one_byte_requests && buffer[i] != terminator_) {
                line += buffer[i];
                continue;
            }
            if (one_byte_requests) line = std::string(1, buffer[i]);
            requests_.push_back(line);
            for (auto& reply : script_(line)) {
                auto timer = std::make_shared<asio::steady_timer>(io_, reply.after);
                timer->async_wait([this, timer, bytes = std::move(reply.bytes)](
                                      const boost::system::error_code& error) {
                    if (!error && master_.is_open()) send(bytes);
                });
            }
            line.clear();
        }
    }
}

void run_until_done(asio::io_context& io, const std::function<asio::awaitable<void>()>& test,
                    std::chrono::milliseconds deadline) {
    bool done = false;
    asio::co_spawn(io, test(), [&](const std::exception_ptr& failure) {
        done = true;
        if (failure) ADD_FAILURE() << "the test coroutine threw";
        io.stop();
    });
    io.restart();
    io.run_for(deadline);
    EXPECT_TRUE(done) << "the test did not finish within " << deadline.count() << " ms";
}

bool run_until(asio::io_context& io, const std::function<bool()>& condition,
               std::chrono::milliseconds deadline) {
    const auto end = std::chrono::steady_clock::now() + deadline;
    while (!condition() && std::chrono::steady_clock::now() < end)
        io.run_one_for(std::chrono::milliseconds(10));
    return condition();
}

}  // namespace ioport::test
