// A serial link to an ioport hub or an ID-2: the one place that touches the tty.
//
// Exactly one transaction is in flight. Each one flushes stale input (unless it follows the last
// reply within a character time), sends the request and frames the reply with a timeout; after
// any failure the link waits for the line to be silent for a full timeout before the next
// request. A reply names neither module nor request, so an answer owed to an earlier request (a
// device that buffered requests while stopped answers them all when it resumes, in order) is
// told from the one in flight by what follows it: a frame followed by more bytes is never taken
// (ReplyWindow), and after a failure, until the device has caught up, a frame is taken only
// once the line stays silent for a timeout after it. On a line that owes nothing the
// reply is taken the moment its terminator arrives. Port loss is an error value, the fd is
// closed, and open() may be called again. The tty is read on a thread of its own (PortReader:
// a read or poll of a tty can wait for a kernel worker); everything else happens on the loop.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "link/asio.hpp"
#include "link/port_reader.hpp"
#include "protocol/error.hpp"
#include "protocol/exchange.hpp"
#include "protocol/reply_window.hpp"

namespace ioport {

using namespace std::chrono_literals;

struct LinkSettings {
    std::string device;                         // /dev/ttyUSB0, /dev/serial/by-id/…, a pty link
    int baud = 115200;                          // 9600, 38400 or 115200
    std::chrono::microseconds timeout = 100ms;  // per attempt, and the silence that ends noise
    int retries = 1;                            // extra attempts after no answer or a bad answer
};

// Attempts by outcome (the result label of ioportd_link_transactions_total).
struct LinkCounters {
    std::uint64_t transactions_ok = 0;
    std::uint64_t no_answer = 0;   // timeouts
    std::uint64_t bad_answer = 0;  // malformed answers, a line that never went quiet
    std::uint64_t error_ack = 0;
    std::uint64_t opens = 0;  // successful opens of the port
    std::uint64_t transactions_failed() const { return no_answer + bad_answer + error_ack; }
    // Opens after the first: how often the port was lost and came back.
    std::uint64_t reopens() const { return opens > 0 ? opens - 1 : 0; }
    void count_failure(Errc code) {
        switch (failure_of(code)) {
            case Failure::no_answer:
                ++no_answer;
                return;
            case Failure::bad_answer:
                ++bad_answer;
                return;
            case Failure::error_ack:
                ++error_ack;
                return;
            case Failure::port:
            case Failure::cancelled:
                return;  // not an answer of the device's: the port's state says it
        }
    }
};

class SerialLink {
  public:
    using Clock = std::chrono::steady_clock;

    SerialLink(const asio::any_io_executor& executor, LinkSettings settings);
    SerialLink(const SerialLink&) = delete;
    SerialLink& operator=(const SerialLink&) = delete;
    ~SerialLink();

    // Opens the device raw 8N1 at the configured baud, exclusive, low latency where the driver
    // allows it. Fails with port_not_found, permission_denied, port_busy, io_error.
    Result<> open();
    void close();
    bool is_open() const { return fd_ >= 0; }
    // The driver accepted ASYNC_LOW_LATENCY (real UARTs and FTDI; a pty does not).
    bool low_latency() const { return low_latency_; }

    // One transaction with up to `retries` extra attempts after a timeout, a malformed reply or
    // a line that never went quiet. An error ack is final at once; so is a port error (the port
    // is closed then).
    asio::awaitable<Result<Reading>> transact(Exchange exchange);

    // A transaction may take (retries + 1) × 13 timeouts on a chattering line (up to 11 waiting
    // for silence before each attempt, one for the answer, one for the silence after it while
    // answers may be owed), but it never
    // waits longer than one timeout without acting: every send, read and wait for silence is
    // bounded by `timeout`. So a link that has not acted for longer than this is stuck, whatever
    // its settings; the watchdog's bound is this one (LinkScheduler::progressing).
    std::chrono::microseconds longest_wait() const { return settings_.timeout; }
    // When the link last acted: an attempt began, bytes arrived, or a wait timed out.
    Clock::time_point last_activity() const { return last_activity_; }

    const LinkSettings& settings() const { return settings_; }
    const LinkCounters& counters() const { return counters_; }
    // Request sent → reply framed, of the last attempt that got a reply (no silence wait).
    std::chrono::microseconds last_round_trip() const { return last_round_trip_; }
    // Bytes read from the port since it was opened (0 while closed).
    std::uint64_t bytes_read() const { return reader_ ? reader_->bytes_read() : 0; }

  private:
    asio::awaitable<Result<Reading>> attempt(const Exchange& exchange);
    asio::awaitable<Result<>> wait_for_silence();
    void arm_timeout(std::chrono::microseconds after);
    void disarm_timeout();
    void wait_for_deadline();
    // The next bytes the reader has, as they come; once the deadline has passed, what came
    // before it (0: nothing, the line was silent).
    asio::awaitable<Result<std::size_t>> next_input(std::string_view during);
    Error port_error(const boost::system::error_code& ec, std::string_view during);

    LinkSettings settings_;
    int fd_ = -1;
    std::unique_ptr<PortReader> reader_;  // while open; stopped before fd_ is closed
    // A timer that never expires, cancelled to wake next_input(): by the reader when input
    // came, and by the deadline.
    asio::steady_timer input_signal_;
    // The timeout of the current attempt is `deadline_` (max: none). The timer is not re-armed
    // for every attempt: it is armed when none is pending, and when it fires before the
    // deadline (which has moved on with later attempts) it waits again.
    asio::steady_timer timer_;
    Clock::time_point deadline_ = Clock::time_point::max();
    bool timer_pending_ = false;
    // Lets a timer completion that was already queued tell that this link is gone.
    std::shared_ptr<SerialLink*> alive_ = std::make_shared<SerialLink*>(this);
    bool timed_out_ = false;
    Clock::time_point last_input_{};  // when the last bytes were read
    Clock::time_point last_activity_ = Clock::now();
    bool needs_silence_ = false;
    // Since the last attempt failed (or the port was opened) no frame has been followed by a
    // timeout of silence: a device that buffered requests may still owe answers to earlier
    // ones, so a frame is taken only once nothing follows it for a timeout.
    bool answers_may_be_owed_ = false;
    bool busy_ = false;
    bool low_latency_ = false;
    std::array<char, 64> read_buffer_{};
    LinkCounters counters_;
    std::chrono::microseconds last_round_trip_{};
};

}  // namespace ioport
