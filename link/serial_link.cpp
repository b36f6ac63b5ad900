#include "link/serial_link.hpp"

#include <fcntl.h>
#include <linux/serial.h>
#include <sys/ioctl.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <system_error>

#include <fmt/format.h>

namespace ioport {
namespace {

using asio::redirect_error;
using asio::use_awaitable;

std::optional<speed_t> speed_for(int baud) {
    switch (baud) {
        case 9600:
            return B9600;
        case 19200:
            return B19200;
        case 38400:
            return B38400;
        case 57600:
            return B57600;
        case 115200:
            return B115200;
        default:
            return std::nullopt;
    }
}

long long as_ms(std::chrono::microseconds d) {
    return std::chrono::duration_cast<std::chrono::milliseconds>(d).count();
}

Error open_error(const std::string& device, int err) {
    switch (err) {
        case ENOENT:
        case ENODEV:
        case ENXIO:
            return {Errc::port_not_found,
                    fmt::format("{} does not exist: check that the adapter is plugged in and the "
                                "path is right (ls /dev/serial/by-id/)",
                                device)};
        case EACCES:
        case EPERM:
            return {Errc::permission_denied,
                    fmt::format("{}: permission denied: add this user to the dialout group "
                                "(sudo usermod -aG dialout $USER, then log in again)",
                                device)};
        case EBUSY:
            return {Errc::port_busy,
                    fmt::format("{} is in use by another program (find it with: fuser -v {})",
                                device, device)};
        default:
            return {Errc::io_error, fmt::format("cannot open {}: {}", device, std::strerror(err))};
    }
}

// Raw 8N1, no flow control, reads never wait on the line discipline.
bool configure_tty(int fd, speed_t speed) {
    termios tio{};
    if (::tcgetattr(fd, &tio) != 0) return false;
    ::cfmakeraw(&tio);
    tio.c_cflag &= ~static_cast<tcflag_t>(CSIZE | CSTOPB | PARENB | CRTSCTS);
    tio.c_cflag |= CS8 | CLOCAL | CREAD;
    tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY);
    tio.c_cc[VMIN] = 1;
    tio.c_cc[VTIME] = 0;
    if (::cfsetispeed(&tio, speed) != 0 || ::cfsetospeed(&tio, speed) != 0) return false;
    return ::tcsetattr(fd, TCSANOW, &tio) == 0;
}

// FTDI adapters otherwise hold a short reply for their 16 ms latency timer.
bool request_low_latency(int fd) {
    serial_struct serial{};
    if (::ioctl(fd, TIOCGSERIAL, &serial) != 0) return false;
    serial.flags |= ASYNC_LOW_LATENCY;
    return ::ioctl(fd, TIOCSSERIAL, &serial) == 0;
}

// One character on the line: start bit, 8 data bits, stop bit.
std::chrono::nanoseconds character_time(int baud) {
    return std::chrono::nanoseconds(10'000'000'000LL / baud);
}

// Writes what the non-blocking `fd` takes now and drops it from `bytes`.
boost::system::error_code write_now(int fd, std::string_view& bytes) {
    const auto written = ::write(fd, bytes.data(), bytes.size());
    if (written >= 0) {
        bytes.remove_prefix(static_cast<std::size_t>(written));
        return {};
    }
    if (errno == EAGAIN || errno == EINTR) return {};
    return {errno, boost::system::system_category()};
}

// The reply to one request as its bytes come in.
class Reply {
  public:
    Reply(const Exchange& exchange, const std::string& device, std::chrono::microseconds timeout)
        : exchange_(exchange),
          device_(device),
          timeout_(timeout),
          window_(exchange.terminator, exchange.reply_length) {}

    ReplyWindow::State feed(std::string_view bytes) {
        if (received_.size() < 64) received_.append(bytes.substr(0, 64 - received_.size()));
        return window_.feed(bytes);
    }

    // The frame, or why it is not this request's reply; only once the window is not waiting.
    Result<std::string> frame() const {
        switch (window_.state()) {
            case ReplyWindow::State::complete:
                return window_.frame();
            case ReplyWindow::State::overflowed:
                return fail(Errc::malformed,
                            fmt::format("answer \"{}…\" is too long: expected {} character(s)",
                                        printable(window_.frame()), exchange_.reply_length));
            case ReplyWindow::State::extra:
                // Answers owed to earlier requests are in the stream: the first frame may be
                // one of them, so none of it is taken (malformed: counted as a bad answer, the
                // line is let fall silent and the request sent again).
                return fail(Errc::malformed,
                            fmt::format("more than one answer came (\"{}\" then \"{}…\"): answers "
                                        "owed to earlier requests are still arriving, so none is "
                                        "taken for this one",
                                        printable(window_.frame()), printable(window_.extra())));
            case ReplyWindow::State::waiting:
                return Unexpected(no_answer());
        }
        return Unexpected(no_answer());
    }

    Error no_answer() const {
        return {Errc::timeout,
                received_.empty()
                    ? fmt::format("{} on {} did not answer within {} ms: check its address "
                                  "switch, its power and the bus cable",
                                  describe(exchange_.target), device_, as_ms(timeout_))
                    : fmt::format("{} on {} sent an incomplete answer \"{}\" within {} ms",
                                  describe(exchange_.target), device_, printable(received_),
                                  as_ms(timeout_))};
    }

  private:
    const Exchange& exchange_;
    const std::string& device_;
    std::chrono::microseconds timeout_;
    ReplyWindow window_;
    std::string received_;  // for the error message of an incomplete answer
};

bool retryable(Errc code) {
    return code == Errc::timeout || code == Errc::malformed || code == Errc::line_noisy;
}

}  // namespace

SerialLink::SerialLink(const asio::any_io_executor& executor, LinkSettings settings)
    : settings_(std::move(settings)),
      input_signal_(executor, asio::steady_timer::time_point::max()),
      timer_(executor) {}

SerialLink::~SerialLink() {
    close();
}

Result<> SerialLink::open() {
    close();
    const auto speed = speed_for(settings_.baud);
    if (!speed)
        return fail(Errc::invalid_argument,
                    fmt::format("{}: baud {} is not supported: use 9600, 38400 or 115200",
                                settings_.device, settings_.baud));
    const int fd = ::open(settings_.device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) return Unexpected(open_error(settings_.device, errno));
    if (!configure_tty(fd, *speed)) {
        const int err = errno;
        ::close(fd);
        return fail(Errc::io_error, fmt::format("{} is not a usable serial port: {}",
                                                settings_.device, std::strerror(err)));
    }
    // Exclusive: a second program on the same bus would interleave transactions.
    ::ioctl(fd, TIOCEXCL);
    low_latency_ = request_low_latency(fd);
    ::tcflush(fd, TCIOFLUSH);
    try {
        reader_ = std::make_unique<PortReader>(input_signal_.get_executor(), fd,
                                               [this] { input_signal_.cancel(); });
    } catch (const std::system_error& e) {  // no thread or eventfd to be had: out of resources
        ::close(fd);
        return fail(Errc::io_error,
                    fmt::format("cannot read {}: {}; the port is closed and is opened again later",
                                settings_.device, e.what()));
    }
    fd_ = fd;
    needs_silence_ = false;
    // Not answers_may_be_owed_: what came before the open is flushed with the port's input, and
    // a device that still answers requests of a port it lost shows a burst (ReplyWindow's
    // `extra`). Confirming every first reply would cost each start and reopen a timeout per link.
    answers_may_be_owed_ = false;
    ++counters_.opens;
    return {};
}

void SerialLink::close() {
    disarm_timeout();
    timer_.cancel();
    timer_pending_ = false;
    input_signal_.cancel();  // a transaction waiting for input ends as cancelled
    reader_.reset();         // before the descriptor it reads is closed
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
}

// A transaction takes about a millisecond and its timeout is a hundred: arming the timer for
// each one cost a timerfd_settime() call and the completion of the cancelled wait, about a sixth
// of the daemon's CPU time while it polls. Deadlines only move later, so a timer armed for an
// earlier one fires first and is armed again for the current deadline: about once a timeout.
void SerialLink::arm_timeout(std::chrono::microseconds after) {
    timed_out_ = false;
    deadline_ = Clock::now() + after;
    if (!timer_pending_) wait_for_deadline();
}

void SerialLink::disarm_timeout() {
    deadline_ = Clock::time_point::max();
}

void SerialLink::wait_for_deadline() {
    timer_pending_ = true;
    timer_.expires_at(deadline_);
    timer_.async_wait(
        [alive = std::weak_ptr<SerialLink*>(alive_)](const boost::system::error_code& ec) {
            const auto self = alive.lock();
            if (ec || !self) return;  // cancelled: closed, or destroyed
            auto& link = **self;
            link.timer_pending_ = false;
            if (link.deadline_ == Clock::time_point::max()) return;  // no attempt in flight: rest
            if (Clock::now() < link.deadline_) {
                link.wait_for_deadline();
                return;
            }
            link.deadline_ = Clock::time_point::max();
            link.timed_out_ = true;
            link.last_activity_ = Clock::now();
            link.input_signal_.cancel();
        });
}

Error SerialLink::port_error(const boost::system::error_code& ec, std::string_view during) {
    if (ec == asio::error::operation_aborted)
        return {Errc::cancelled, fmt::format("{}: {} cancelled", settings_.device, during)};
    close();
    const bool lost = ec == asio::error::eof || ec.value() == EIO || ec.value() == ENXIO ||
                      ec.value() == ENODEV || ec.value() == EBADF;
    if (lost)
        return {Errc::port_lost,
                fmt::format("{} was lost while {} ({}): the adapter was unplugged or the device "
                            "went away; the port has been closed",
                            settings_.device, during, ec.message())};
    return {Errc::io_error, fmt::format("{}: {} failed: {}; the port has been closed",
                                        settings_.device, during, ec.message())};
}

// The timer's handler only marks the deadline passed; whether anything came before it is judged
// here, by what the reader holds. A process short of the CPU can meet the expired timer and the
// input that came in time in one turn of its loop, the timer first: those bytes are input like
// any other, and the timeout stands only when there are none. Bytes the kernel has not yet
// handed to the tty (its flip buffer) are not seen: the line is judged as the kernel handed it
// over.
asio::awaitable<Result<std::size_t>> SerialLink::next_input(std::string_view during) {
    for (;;) {
        if (!reader_) co_return Unexpected(port_error(asio::error::operation_aborted, during));
        if (const auto n = reader_->take(read_buffer_); n > 0) co_return n;
        if (const auto ec = reader_->error()) co_return Unexpected(port_error(ec, during));
        if (timed_out_) co_return std::size_t{0};
        boost::system::error_code ignored;  // cancelled: input came, or the deadline passed
        co_await input_signal_.async_wait(redirect_error(use_awaitable, ignored));
    }
}

// The coroutine owns the exchange, so callers may pass a temporary.
asio::awaitable<Result<Reading>> SerialLink::transact(Exchange exchange) {
    for (int tried = 0;; ++tried) {
        auto reading = co_await attempt(exchange);
        if (reading || tried >= settings_.retries || !retryable(reading.error().code))
            co_return reading;
    }
}

asio::awaitable<Result<Reading>> SerialLink::attempt(const Exchange& exchange) {
    if (!is_open())
        co_return fail(Errc::port_closed, fmt::format("{} is not open", settings_.device));
    if (busy_)
        co_return fail(Errc::invalid_argument,
                       fmt::format("{}: a transaction is already in flight", settings_.device));
    busy_ = true;
    struct Release {
        bool& busy;
        ~Release() { busy = false; }
    } release{busy_};
    last_activity_ = Clock::now();

    if (needs_silence_) {
        if (auto quiet = co_await wait_for_silence(); !quiet) {
            counters_.count_failure(quiet.error().code);
            co_return Unexpected(quiet.error());
        }
    }
    // Bytes that came while the line was idle (noise, a stray byte) would be taken for the start
    // of the reply: they are flushed. Within a character time of the last reply nothing can
    // have come yet, so back-to-back polling skips this system call (a fifth of them).
    auto sent = Clock::now();
    if (sent - last_input_ >= character_time(settings_.baud)) {
        ::tcflush(fd_, TCIFLUSH);
        reader_->discard();
        sent = Clock::now();
    }

    arm_timeout(settings_.timeout);
    // A request is a few bytes into an empty output buffer: write() takes it whole, at once. The
    // reader sends only what write() did not take, if ever (the other side not reading).
    std::string_view unsent = exchange.request;
    if (const auto ec = write_now(fd_, unsent)) {
        disarm_timeout();
        answers_may_be_owed_ = true;  // part of the request may have gone out
        co_return Unexpected(port_error(ec, "sending"));
    }
    if (!unsent.empty()) reader_->send(unsent);
    // The reply is read here rather than in a coroutine of its own: one coroutine frame less to
    // allocate and resume per transaction.
    Reply reply(exchange, settings_.device, settings_.timeout);
    std::optional<Error> failed;
    // Until a frame is complete, then (only when answers may be owed) until the line has been
    // silent for a timeout after it.
    bool confirming = false;
    Clock::time_point framed{};
    for (;;) {
        auto input = co_await next_input("reading");
        if (!input) {
            disarm_timeout();
            failed = input.error();
            break;
        }
        if (*input == 0) break;  // nothing came in time
        const auto n = *input;
        last_input_ = Clock::now();
        last_activity_ = last_input_;
        const auto state = reply.feed({read_buffer_.data(), n});
        if (state == ReplyWindow::State::waiting) continue;
        if (state != ReplyWindow::State::complete || confirming) {
            disarm_timeout();
            break;
        }
        framed = last_input_;
        // A healthy line owes nothing: the frame is the reply at once, no slower than before.
        if (!answers_may_be_owed_) {
            disarm_timeout();
            break;
        }
        // Answers may be owed to earlier requests (one failed, or the port was just opened): a
        // device that buffered them sends them first, in order, then this request's. The frame
        // is this request's only if nothing follows it for a timeout; anything that does makes
        // the window `extra`.
        confirming = true;
        arm_timeout(settings_.timeout);
    }
    if (!failed && timed_out_ && is_open() && reader_->unsent() > 0) {
        // The request never went out whole: the other side is not reading.
        reader_->drop_unsent();
        ::tcflush(fd_, TCOFLUSH);
        failed = Error{Errc::timeout,
                       fmt::format("{}: could not send to {} within {} ms", settings_.device,
                                   describe(exchange.target), as_ms(settings_.timeout))};
    }
    Result<std::string> frame = failed ? Result<std::string>(Unexpected(*failed)) : reply.frame();
    Result<Reading> reading = frame ? decode(exchange, *frame) : Unexpected(frame.error());
    if (frame) {
        last_round_trip_ = std::chrono::duration_cast<std::chrono::microseconds>(framed - sent);
        // One frame then a timeout of silence: the device has caught up.
        answers_may_be_owed_ = false;
    }
    if (reading) {
        ++counters_.transactions_ok;
    } else {
        counters_.count_failure(reading.error().code);
        const auto code = reading.error().code;
        // Whatever else is on its way belongs to this failed request or an earlier one: let it
        // pass first, and take the next frame only once nothing follows it.
        if (code == Errc::timeout || code == Errc::malformed) {
            needs_silence_ = true;
            answers_may_be_owed_ = true;
        }
        if (code == Errc::malformed)
            reading.error().message = fmt::format("{} on {}: {}", describe(exchange.target),
                                                  settings_.device, reading.error().message);
    }
    co_return reading;
}

asio::awaitable<Result<>> SerialLink::wait_for_silence() {
    // Bounded: a line that chatters for ten timeouts in a row is reported, not waited on forever.
    const auto deadline = Clock::now() + 10 * settings_.timeout;
    for (;;) {
        arm_timeout(settings_.timeout);
        auto input = co_await next_input("waiting for silence");
        if (!input) {
            disarm_timeout();
            co_return Unexpected(input.error());
        }
        if (*input == 0) {  // silent for a timeout
            needs_silence_ = false;
            co_return Result<>{};
        }
        last_activity_ = Clock::now();
        // Not silent: a timeout more. Bytes found once the deadline had passed came before the
        // timer ran, which may be long after its deadline when the loop is short of the CPU:
        // they say nothing of how long the line has chattered, so only bytes taken as they came
        // make it noisy.
        if (timed_out_) continue;
        if (last_activity_ >= deadline) {
            disarm_timeout();
            answers_may_be_owed_ = true;
            co_return fail(Errc::line_noisy,
                           fmt::format("{}: the line never stayed silent for {} ms: check for "
                                       "noise, a wrong baud rate or another device talking",
                                       settings_.device, as_ms(settings_.timeout)));
        }
    }
}

}  // namespace ioport
