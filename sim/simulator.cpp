#include "sim/simulator.hpp"

#include <fcntl.h>
#include <stdlib.h>
#include <sys/prctl.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include <fmt/format.h>

#include "sim/control.hpp"

namespace ioport::sim {
namespace {

using asio::redirect_error;
using asio::use_awaitable;

Error os_error(std::string_view what, const std::string& path) {
    return {Errc::io_error, fmt::format("{} {}: {}", what, path, std::strerror(errno))};
}

// Replaces `link` atomically, so a master polling for it never sees a dangling half-state.
Result<> point_link(const std::string& link, const std::string& target) {
    const std::string temporary = link + ".new";
    ::unlink(temporary.c_str());
    if (::symlink(target.c_str(), temporary.c_str()) != 0)
        return Unexpected(os_error("cannot create the link", temporary));
    if (::rename(temporary.c_str(), link.c_str()) != 0) {
        ::unlink(temporary.c_str());
        return Unexpected(os_error("cannot create the link", link));
    }
    return {};
}

}  // namespace

Simulator::Simulator(asio::io_context& io, DeviceModel& model, SimulatorSettings settings)
    : io_(io),
      model_(model),
      settings_(std::move(settings)),
      master_(io),
      answer_timer_(io),
      replug_timer_(io),
      chatter_timer_(io) {}

Simulator::~Simulator() {
    stop();
}

Result<> Simulator::start() {
    // A device answers on time to the character. The kernel lets a timer fire up to its slack
    // late, 50 µs by default: added to every modelled answer, that is 5 % of a dim16 read at
    // 115200 baud, and the simulator, not the master, would be slow. What lateness remains is
    // the machine's wake-up, which answer_clock_ learns and sets the timers early by.
    if (settings_.line_timing) ::prctl(PR_SET_TIMERSLACK, 1UL);
    if (settings_.control_path) {
        ::unlink(settings_.control_path->c_str());
        boost::system::error_code ec;
        control_.emplace(io_);
        const asio::local::stream_protocol::endpoint endpoint(*settings_.control_path);
        if (control_->open(endpoint.protocol(), ec); !ec) control_->bind(endpoint, ec);
        if (!ec) control_->listen(asio::socket_base::max_listen_connections, ec);
        if (ec)
            return fail(Errc::io_error, fmt::format("cannot listen on {}: {}",
                                                    *settings_.control_path, ec.message()));
        asio::co_spawn(io_, accept_control(), asio::detached);
    }
    return plug();
}

void Simulator::stop() {
    unplug();
    replug_timer_.cancel();
    chatter_timer_.cancel();
    if (control_) {
        boost::system::error_code ignored;
        control_->close(ignored);
        control_.reset();
        ::unlink(settings_.control_path->c_str());
    }
}

Result<> Simulator::plug() {
    if (master_.is_open()) return {};
    const int master = ::posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC | O_NONBLOCK);
    if (master < 0) return Unexpected(os_error("cannot open", "/dev/ptmx"));
    std::array<char, 128> name{};
    if (::grantpt(master) != 0 || ::unlockpt(master) != 0 ||
        ::ptsname_r(master, name.data(), name.size()) != 0) {
        ::close(master);
        return Unexpected(os_error("cannot set up", "/dev/ptmx"));
    }
    pty_name_ = name.data();
    slave_fd_ = ::open(pty_name_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
    termios tio{};
    if (slave_fd_ < 0 || ::tcgetattr(slave_fd_, &tio) != 0) {
        ::close(master);
        return Unexpected(os_error("cannot open", pty_name_));
    }
    // Raw before any master opens it: no echo of our answers back into our own input.
    ::cfmakeraw(&tio);
    ::tcsetattr(slave_fd_, TCSANOW, &tio);
    master_.assign(master);
    if (auto linked = point_link(settings_.link_path, pty_name_); !linked) {
        unplug();
        return linked;
    }
    const auto generation = ++plug_generation_;
    asio::co_spawn(io_, read_requests(generation), asio::detached);
    asio::co_spawn(io_, write_answers(generation), asio::detached);
    return {};
}

void Simulator::unplug() {
    if (!master_.is_open()) return;
    ::unlink(settings_.link_path.c_str());
    ++plug_generation_;
    boost::system::error_code ignored;
    master_.close(ignored);
    ::close(slave_fd_);
    slave_fd_ = -1;
    due_.clear();
    answer_timer_.cancel();
}

std::chrono::microseconds Simulator::wire_time(std::size_t bytes) const {
    if (!settings_.line_timing) return {};
    return std::chrono::microseconds{static_cast<long long>(bytes) * 10 * 1'000'000 /
                                     settings_.baud};
}

asio::awaitable<void> Simulator::read_requests(std::uint64_t generation) {
    std::array<char, 256> buffer{};
    while (generation == plug_generation_) {
        boost::system::error_code ec;
        const auto n = co_await master_.async_read_some(asio::buffer(buffer),
                                                        redirect_error(use_awaitable, ec));
        if (generation != plug_generation_) co_return;
        if (ec == asio::error::eof || ec.value() == EIO) {
            // No master has the pty open (only if our own slave fd was lost): poll for one.
            asio::steady_timer idle(io_, 10ms);
            co_await idle.async_wait(redirect_error(use_awaitable, ec));
            continue;
        }
        if (ec) co_return;
        const auto now = Clock::now();
        const std::string_view bytes(buffer.data(), n);
        const auto received = std::chrono::duration_cast<std::chrono::microseconds>(now - started_);
        for (auto& answer : model_.receive(bytes, received)) {
            const auto start = std::max(
                now + wire_time(n) + settings_.turnaround + answer.extra_delay, line_free_);
            const auto done = start + wire_time(answer.bytes.size());
            line_free_ = std::max(line_free_, done);
            due_.emplace(done, std::move(answer.bytes));
        }
        answer_timer_.cancel();  // wake the writer: its next deadline may have moved
    }
}

asio::awaitable<void> Simulator::write_answers(std::uint64_t generation) {
    while (generation == plug_generation_) {
        boost::system::error_code ec;
        const auto wake =
            due_.empty() ? Clock::now() + 1h : due_.begin()->first - answer_clock_.advance();
        if (wake > Clock::now()) {
            answer_timer_.expires_at(wake);
            co_await answer_timer_.async_wait(redirect_error(use_awaitable, ec));
            continue;
        }
        if (settings_.line_timing) answer_clock_.answered(Clock::now() - due_.begin()->first);
        const std::string bytes = std::move(due_.begin()->second);
        due_.erase(due_.begin());
        co_await asio::async_write(master_, asio::buffer(bytes), redirect_error(use_awaitable, ec));
        if (ec && generation == plug_generation_) co_return;
    }
}

void Simulator::apply(const PortAction& action) {
    switch (action.kind) {
        case PortAction::Kind::replug:
            replug_timer_.cancel();
            if (auto plugged = plug(); !plugged)
                (void)std::fprintf(stderr, "ioport-sim: %s\n", plugged.error().message.c_str());
            return;
        case PortAction::Kind::unplug:
            unplug();
            if (!action.after) return;
            replug_timer_.expires_after(*action.after);
            replug_timer_.async_wait([this](const boost::system::error_code& ec) {
                if (!ec) apply(PortAction{PortAction::Kind::replug, std::nullopt});
            });
            return;
        case PortAction::Kind::chatter:
            chatter_timer_.cancel();
            if (action.after) chatter(*action.after);
            return;
    }
}

void Simulator::chatter(std::chrono::microseconds every) {
    chatter_timer_.expires_after(every);
    chatter_timer_.async_wait([this, every](const boost::system::error_code& ec) {
        if (ec) return;  // chatter off, or stopped
        // Never a hex digit nor a terminator: noise is noise, whatever it lands in. Written
        // as it comes, beside the answers, as a real disturbance would; a full pty drops it.
        static constexpr std::string_view noise = "GHJKLMNPQRSTUVWXYZ#*?!~";
        if (master_.is_open()) {
            const char byte = noise[static_cast<std::size_t>(++chatter_count_) % noise.size()];
            [[maybe_unused]] const ssize_t written = ::write(master_.native_handle(), &byte, 1);
        }
        chatter(every);
    });
}

asio::awaitable<void> Simulator::accept_control() {
    while (control_ && control_->is_open()) {
        boost::system::error_code ec;
        auto socket = co_await control_->async_accept(redirect_error(use_awaitable, ec));
        if (ec) co_return;
        asio::co_spawn(io_, serve_control(std::move(socket)), asio::detached);
    }
}

asio::awaitable<void> Simulator::serve_control(asio::local::stream_protocol::socket socket) {
    asio::streambuf input(4096);
    for (;;) {
        boost::system::error_code ec;
        const auto n =
            co_await asio::async_read_until(socket, input, '\n', redirect_error(use_awaitable, ec));
        if (ec) co_return;
        std::string line(asio::buffers_begin(input.data()),
                         asio::buffers_begin(input.data()) + static_cast<std::ptrdiff_t>(n) - 1);
        input.consume(n);
        // The clock is the simulator's, not the model's: the model only sees the times it is
        // given. steady_clock is CLOCK_MONOTONIC, the same in every process on the machine.
        if (line == "clock" || line == "clock\r") {
            const auto micros = [](Clock::duration d) {
                return std::chrono::duration_cast<std::chrono::microseconds>(d).count();
            };
            const auto text = fmt::format("{} {}\nok\n", micros(started_.time_since_epoch()),
                                          micros(Clock::now() - started_));
            co_await asio::async_write(socket, asio::buffer(text),
                                       redirect_error(use_awaitable, ec));
            if (ec) co_return;
            continue;
        }
        auto reply = execute(model_, line);
        if (reply.action) apply(*reply.action);
        co_await asio::async_write(socket, asio::buffer(reply.text),
                                   redirect_error(use_awaitable, ec));
        if (ec) co_return;
    }
}

}  // namespace ioport::sim
