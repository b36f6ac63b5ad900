// The serial link against a device the test scripts byte for byte on a pty.
#include <sys/socket.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <thread>

#include "link/port_reader.hpp"
#include "link/serial_link.hpp"
#include "tests/support/gateway.hpp"
#include "tests/support/pty_pair.hpp"
#include "tests/support/timing.hpp"

namespace ioport {
namespace {

using namespace std::chrono_literals;
using test::PtyDevice;
using test::Reply;
using test::run_until_done;
using Clock = std::chrono::steady_clock;

const ModuleAddress dim0{ModuleType::dim16, 0};
const ModuleAddress dim1{ModuleType::dim16, 1};
const ModuleAddress dom0{ModuleType::dom16, 0};

Exchange read(ModuleAddress module) {
    return *make_exchange(module);
}

// The links' timeout here, and what the scripted device's timings are measured against. Wide, so
// that what a test tells apart (an answer in time or late, a silence or noise) stays apart on a
// machine whose cores are busy: there the test's loop, the link's reader and the kernel's tty
// worker can each wait tens of milliseconds for the CPU.
constexpr auto timeout = 250ms;

class SerialLinkTest : public ::testing::Test {
  protected:
    void SetUp() override { ASSERT_TRUE(link.open()) << link.open().error().message; }
    LinkSettings settings(std::chrono::microseconds limit, int retries) {
        return {device.path(), 115200, limit, retries};
    }
    asio::io_context io;
    PtyDevice device{io};
    SerialLink link{io.get_executor(), settings(timeout, 0)};
};

// Runs transactions in order on the test's io_context and returns every outcome with its
// duration. `between` runs before transaction i (for scripted line noise and the like).
struct TimedResult {
    Result<Reading> result;
    Clock::duration elapsed;
};
std::vector<TimedResult> transact_all(asio::io_context& io, SerialLink& link,
                                      const std::vector<Exchange>& exchanges,
                                      const std::function<void(std::size_t)>& between = {}) {
    std::vector<TimedResult> outcomes;
    run_until_done(io, [&]() -> asio::awaitable<void> {
        for (std::size_t i = 0; i < exchanges.size(); ++i) {
            if (between) between(i);
            const auto start = Clock::now();
            auto result = co_await link.transact(exchanges[i]);
            outcomes.push_back({std::move(result), Clock::now() - start});
        }
    });
    return outcomes;
}

TEST_F(SerialLinkTest, ReadsAReplySplitAcrossWrites) {
    device.serve([](const std::string&) {
        return std::vector<Reply>{{0ms, "80"}, {timeout / 10, "00\r"}};
    });
    const auto outcomes = transact_all(io, link, {read(dim0)});
    ASSERT_EQ(outcomes.size(), 1u);
    ASSERT_TRUE(outcomes[0].result) << outcomes[0].result.error().message;
    EXPECT_EQ(outcomes[0].result->raw[0], 0x8000);
    EXPECT_EQ(device.requests(), std::vector<std::string>{"a0"});
    EXPECT_EQ(link.counters().transactions_ok, 1u);
    EXPECT_FALSE(link.low_latency());  // a pty has no ASYNC_LOW_LATENCY
}

TEST_F(SerialLinkTest, TimesOutAfterTheConfiguredTimeout) {
    device.serve([](const std::string&) { return std::vector<Reply>{}; });
    const auto outcomes = transact_all(io, link, {read(dim0)});
    ASSERT_EQ(outcomes.size(), 1u);
    const auto& [reading, elapsed] = outcomes[0];
    ASSERT_FALSE(reading);
    EXPECT_EQ(reading.error().code, Errc::timeout);
    EXPECT_NE(reading.error().message.find("dim16 0 on " + device.path() +
                                           " did not answer within 250 ms"),
              std::string::npos)
        << reading.error().message;
    EXPECT_GE(elapsed, timeout);
    EXPECT_LT(elapsed, timeout + 2s * test::slowdown);
    EXPECT_EQ(link.counters().transactions_failed(), 1u);
}

TEST_F(SerialLinkTest, ALateAnswerIsNeverTakenForTheNextModule) {
    device.serve([](const std::string& request) {
        // After the timeout, within the silence the link then waits for.
        if (request == "a0") return std::vector<Reply>{{timeout * 8 / 5, "1111\r"}};
        return std::vector<Reply>{{0ms, "2222\r"}};
    });
    const auto outcomes = transact_all(io, link, {read(dim0), read(dim1)});
    ASSERT_EQ(outcomes.size(), 2u);
    EXPECT_EQ(outcomes[0].result.error().code, Errc::timeout);
    ASSERT_TRUE(outcomes[1].result) << outcomes[1].result.error().message;
    EXPECT_EQ(outcomes[1].result->raw[0], 0x2222);
}

// A device that buffered requests while it was stopped (SIGSTOP, a starved machine: issue 47)
// answers them all when it resumes, in order: dim16 1's owed answer first, then dccim 0's own.
// A reply names neither, so the first frame of the burst must not be taken for dccim 0's; the
// request is sent again once the line is silent, and that answer alone is taken.
std::vector<Reply> owed_then_own(std::string owed, std::string own, std::chrono::milliseconds gap) {
    return {{0ms, std::move(owed)}, {gap, std::move(own)}};
}

class OwedAnswers : public SerialLinkTest {
  protected:
    void SetUp() override {
        SerialLinkTest::SetUp();
        link.close();
        ASSERT_TRUE(retrying.open());
    }
    SerialLink retrying{io.get_executor(), settings(timeout, 1)};
};

TEST_F(OwedAnswers, AReadNeverTakesTheAnswerOwedToAnEarlierRead) {
    const ModuleAddress dccim0{ModuleType::dccim, 0};
    auto gap = 0ms;
    int dccim_requests = 0;
    device.serve([&](const std::string& request) {
        if (request == "a1") return std::vector<Reply>{};  // stopped: buffers, answers later
        if (++dccim_requests == 1) return owed_then_own("400C\r", "1234\r", gap);
        return std::vector<Reply>{{0ms, "1234\r"}};
    });
    // One burst, or the own answer well within a timeout.
    for (const std::chrono::milliseconds each : {0ms, timeout * 2 / 5}) {
        SCOPED_TRACE(each.count());
        gap = each;
        dccim_requests = 0;
        const auto outcomes = transact_all(io, retrying, {read(dim1), read(dccim0)});
        ASSERT_EQ(outcomes.size(), 2u);
        EXPECT_FALSE(outcomes[0].result);
        ASSERT_TRUE(outcomes[1].result) << outcomes[1].result.error().message;
        EXPECT_EQ(outcomes[1].result->raw[0], 0x1234) << "dim16 1's answer served as dccim 0's";
        EXPECT_EQ(dccim_requests, 2) << "the burst was not discarded and the request sent again";
    }
}

// §3.2: a write is confirmed only by its own "1". Here dom16 0's write was buffered and is
// acknowledged late, just before dom16 1 refuses its own write: dom16 1's must not be
// confirmed by dom16 0's "1".
TEST_F(OwedAnswers, AWriteIsNeverConfirmedByTheAcknowledgementOwedToAnEarlierWrite) {
    const ModuleAddress dom1{ModuleType::dom16, 1};
    auto gap = 0ms;
    int dom1_requests = 0;
    device.serve([&](const std::string& request) {
        if (request.starts_with("b0")) return std::vector<Reply>{};
        if (++dom1_requests == 1) return owed_then_own("1\r", "0\r", gap);
        return std::vector<Reply>{{0ms, "0\r"}};
    });
    for (const std::chrono::milliseconds each : {0ms, timeout * 2 / 5}) {
        SCOPED_TRACE(each.count());
        gap = each;
        dom1_requests = 0;
        const auto outcomes = transact_all(
            io, retrying, {*make_exchange(dom0, 0x0001), *make_exchange(dom1, 0x0002)});
        ASSERT_EQ(outcomes.size(), 2u);
        EXPECT_FALSE(outcomes[0].result);
        ASSERT_FALSE(outcomes[1].result) << "dom16 1's write confirmed by dom16 0's answer";
        EXPECT_EQ(outcomes[1].result.error().code, Errc::error_ack)
            << outcomes[1].result.error().message;
    }
}

// After a failure the first frame waits for a timeout of silence; once one has, the device has
// caught up and the next reply is taken at once again.
TEST_F(OwedAnswers, OnceTheDeviceCaughtUpRepliesAreTakenAtOnceAgain) {
    device.serve([&](const std::string& request) {
        if (request == "a1") return std::vector<Reply>{};
        return std::vector<Reply>{{0ms, "0042\r"}};
    });
    const auto outcomes = transact_all(io, retrying, {read(dim1), read(dim0), read(dim0)});
    ASSERT_EQ(outcomes.size(), 3u);
    ASSERT_TRUE(outcomes[1].result) << outcomes[1].result.error().message;
    ASSERT_TRUE(outcomes[2].result) << outcomes[2].result.error().message;
    EXPECT_GE(outcomes[1].elapsed, 2 * timeout);  // a silence before, a silence after
    // No silence after the frame: well under the timeout a confirmation takes, even busy.
    EXPECT_LT(outcomes[2].elapsed, outcomes[1].elapsed / 2);
}

TEST_F(SerialLinkTest, StaleInputIsFlushedBeforeARequest) {
    device.serve([](const std::string&) { return std::vector<Reply>{{0ms, "0001\r"}}; });
    device.send("FFFF\r");  // unasked: must not be the answer
    const auto outcomes = transact_all(io, link, {read(dim0)});
    ASSERT_TRUE(outcomes.at(0).result) << outcomes[0].result.error().message;
    EXPECT_EQ(outcomes[0].result->raw[0], 0x0001);
}

// Between back-to-back transactions the flush is skipped (nothing can have come within a
// character time of the last reply); bytes that came while the link was idle are still flushed.
TEST_F(SerialLinkTest, InputThatCameWhileTheLinkWasIdleIsFlushed) {
    device.serve([](const std::string&) { return std::vector<Reply>{{0ms, "0001\r"}}; });
    const auto outcomes = transact_all(io, link, {read(dim0), read(dim0)}, [&](std::size_t i) {
        if (i != 1) return;
        const auto idle_since = Clock::now();  // after the last reply
        const auto before = link.bytes_read();
        device.send("FFFF\r");  // unasked
        EXPECT_TRUE(test::eventually([&] { return link.bytes_read() >= before + 5; }))
            << "the unasked bytes never reached the link";
        // And the line idle for longer than a character time (87 µs at 115200 baud): the link
        // only flushes after that. Time is what this waits for, not a condition.
        std::this_thread::sleep_until(idle_since + 200us);
    });
    ASSERT_EQ(outcomes.size(), 2u);
    ASSERT_TRUE(outcomes[1].result) << outcomes[1].result.error().message;
    EXPECT_EQ(outcomes[1].result->raw[0], 0x0001);
}

TEST_F(SerialLinkTest, MalformedAndOverlongAnswersAreErrorsAndTheLinkRecovers) {
    int n = 0;
    device.serve([&](const std::string&) {
        switch (n++) {
            case 0:
                return std::vector<Reply>{{0ms, "12G4\r"}};
            case 1:
                return std::vector<Reply>{{0ms, "FFFFFFFFFFFFFFFFFFFF\r"}};
            case 2:
                return std::vector<Reply>{{0ms, "123\r"}};
            default:
                return std::vector<Reply>{{0ms, "ABCD\r"}};
        }
    });
    const auto outcomes = transact_all(io, link, {read(dim0), read(dim0), read(dim0), read(dim0)});
    ASSERT_EQ(outcomes.size(), 4u);
    for (int i = 0; i < 3; ++i) {
        ASSERT_FALSE(outcomes[i].result) << i;
        EXPECT_EQ(outcomes[i].result.error().code, Errc::malformed) << i;
    }
    ASSERT_TRUE(outcomes[3].result) << outcomes[3].result.error().message;
    EXPECT_EQ(outcomes[3].result->raw[0], 0xABCD);
    EXPECT_EQ(link.counters().transactions_failed(), 3u);
    EXPECT_EQ(link.counters().transactions_ok, 1u);
}

TEST_F(SerialLinkTest, RetriesAMissingAnswerButNotAnErrorAck) {
    SerialLink retrying(io.get_executor(), settings(timeout, 2));
    link.close();
    ASSERT_TRUE(retrying.open());
    int reads = 0;
    device.serve([&](const std::string& request) {
        if (request.starts_with("b")) return std::vector<Reply>{{0ms, "0\r"}};
        if (++reads < 3) return std::vector<Reply>{};  // silent twice, then answers
        return std::vector<Reply>{{0ms, "0042\r"}};
    });
    const auto outcomes = transact_all(io, retrying, {read(dim0), *make_exchange(dom0, 0x00FF)});
    ASSERT_EQ(outcomes.size(), 2u);
    ASSERT_TRUE(outcomes[0].result) << outcomes[0].result.error().message;
    EXPECT_EQ(outcomes[0].result->raw[0], 0x0042);
    ASSERT_FALSE(outcomes[1].result);
    EXPECT_EQ(outcomes[1].result.error().code, Errc::error_ack);
    EXPECT_EQ(device.requests(), (std::vector<std::string>{"a0", "a0", "a0", "b000FF"}));
    EXPECT_EQ(retrying.counters().transactions_failed(), 3u);  // two timeouts, one error ack
}

TEST_F(SerialLinkTest, ALineThatNeverFallsSilentIsReportedNotWaitedOnForever) {
    device.serve([](const std::string&) { return std::vector<Reply>{}; });
    // After the first timeout, a byte of noise every 10 ms: never a timeout's silence.
    asio::steady_timer noise(io);
    std::function<void(const boost::system::error_code&)> chatter = [&](const auto& ec) {
        if (ec) return;
        device.send("~");
        noise.expires_after(10ms);
        noise.async_wait(chatter);
    };
    const auto outcomes = transact_all(io, link, {read(dim0), read(dim0)}, [&](std::size_t i) {
        if (i == 1) chatter({});
    });
    noise.cancel();
    ASSERT_EQ(outcomes.size(), 2u);
    EXPECT_EQ(outcomes[0].result.error().code, Errc::timeout);
    ASSERT_FALSE(outcomes[1].result);
    EXPECT_EQ(outcomes[1].result.error().code, Errc::line_noisy);
    EXPECT_GE(outcomes[1].elapsed, 10 * timeout);
    EXPECT_LT(outcomes[1].elapsed, 10 * timeout + 5s * test::slowdown);
}

// A loop short of the CPU judges a deadline late, and the answer that came in time may wait in
// the tty unread by then: the expired timer and the readable tty meet in one turn, the timer
// first. Here the test's own loop stalls past the link's deadline, as a starved daemon's does,
// while the answer comes within it; after the stall the answer (in the tty before the link's timer
// runs) and the link's timer run in one turn, the timer last. The answer came in time: it is the
// reply, not a timeout. The test writes the answer itself, at a moment of its own: the device's
// reading of the request is the kernel's to deliver, late on a busy machine.
TEST_F(SerialLinkTest, AnAnswerThatCameInTimeIsTakenWhenTheLoopRunsTheTimerFirst) {
    const auto stretched = timeout * test::slowdown;
    SerialLink slow(io.get_executor(), settings(stretched, 0));
    link.close();
    ASSERT_TRUE(slow.open());
    // The link arms its deadline (later than `before` + its timeout) before the stall begins.
    const auto before = Clock::now();
    asio::steady_timer stall(io, 1ms);
    stall.async_wait([&](const boost::system::error_code& ec) {
        if (!ec) test::pace_until(Clock::now() + stretched + stretched / 4);
    });
    asio::steady_timer answer(io, before + stretched / 2);
    answer.async_wait([&](const boost::system::error_code& ec) {
        if (ec) return;
        device.send("8000\r");
        // Read from the tty, not only in the kernel's hands, when the link's timer runs.
        EXPECT_TRUE(test::eventually([&] { return slow.bytes_read() >= 5; }, 10s * test::slowdown));
    });
    const auto outcomes = transact_all(io, slow, {read(dim0)});
    ASSERT_EQ(outcomes.size(), 1u);
    ASSERT_TRUE(outcomes[0].result) << outcomes[0].result.error().message;
    EXPECT_EQ(outcomes[0].result->raw[0], 0x8000);
    EXPECT_EQ(slow.counters().no_answer, 0u);
}

// The same for the silence the link waits for after a failure: noise that came within the
// timeout but was read only after the timer's handler ran breaks the silence, and the request
// goes again only once the line has been silent for a timeout after the noise.
TEST_F(SerialLinkTest, NoiseThatCameInTimeBreaksTheSilenceWhenTheLoopRunsTheTimerFirst) {
    const auto stretched = timeout * test::slowdown;
    SerialLink retrying(io.get_executor(), settings(stretched, 1));
    link.close();
    ASSERT_TRUE(retrying.open());
    std::vector<Clock::time_point> heard;
    device.serve([&](const std::string&) {
        heard.push_back(Clock::now());
        return std::vector<Reply>{};
    });
    // A malformed answer just after the request: the link then waits for a stretched of silence,
    // which begins after `start` and ends later than start + stretched.
    asio::steady_timer garbage(io, 1ms);
    asio::steady_timer stall(io);
    asio::steady_timer noise(io);
    Clock::time_point noise_sent{};
    garbage.async_wait([&](const boost::system::error_code& ec) {
        if (ec) return;
        const auto start = Clock::now();
        device.send("12G4\r");
        stall.expires_at(start + stretched / 10);
        stall.async_wait([&](const boost::system::error_code& error) {
            if (!error) test::pace_until(Clock::now() + stretched + stretched / 4);
        });
        noise.expires_at(start + stretched / 2);
        noise.async_wait([&](const boost::system::error_code& error) {
            if (error) return;
            noise_sent = Clock::now();
            const auto before = retrying.bytes_read();
            device.send("~");
            EXPECT_TRUE(test::eventually([&] { return retrying.bytes_read() > before; },
                                         10s * test::slowdown));
        });
    });
    const auto outcomes = transact_all(io, retrying, {read(dim0)});
    ASSERT_EQ(outcomes.size(), 1u);
    EXPECT_GE(retrying.counters().bad_answer, 1u);  // the garbage
    // Both requests at the device (the kernel delivers them, late on a busy machine).
    ASSERT_TRUE(test::run_until(
        io, [&] { return heard.size() >= 2; }, 10s * test::slowdown));
    ASSERT_NE(noise_sent, Clock::time_point{});
    EXPECT_GE(heard[1] - noise_sent, stretched)
        << "the request went again within a stretched of noise";
}

TEST_F(SerialLinkTest, PortLossIsAnErrorValueAndClosesThePort) {
    device.serve([](const std::string&) { return std::vector<Reply>{}; });
    device.hang_up();
    const auto outcomes = transact_all(io, link, {read(dim0), read(dim0)});
    ASSERT_EQ(outcomes.size(), 2u);
    ASSERT_FALSE(outcomes[0].result);
    EXPECT_EQ(outcomes[0].result.error().code, Errc::port_lost)
        << outcomes[0].result.error().message;
    EXPECT_FALSE(link.is_open());
    EXPECT_EQ(outcomes[1].result.error().code, Errc::port_closed);
}

TEST(SerialLinkOpen, ErrorsSayWhatToDo) {
    asio::io_context io;
    SerialLink missing(io.get_executor(), {"/dev/serial/by-id/no-such-adapter", 115200, 100ms, 1});
    const auto not_found = missing.open();
    ASSERT_FALSE(not_found);
    EXPECT_EQ(not_found.error().code, Errc::port_not_found);
    EXPECT_NE(not_found.error().message.find("ls /dev/serial/by-id/"), std::string::npos);

    const std::string file = ::testing::TempDir() + "/not-a-tty";
    std::ofstream(file) << "x";
    SerialLink regular(io.get_executor(), {file, 115200, 100ms, 1});
    const auto not_tty = regular.open();
    ASSERT_FALSE(not_tty);
    EXPECT_EQ(not_tty.error().code, Errc::io_error);
    EXPECT_NE(not_tty.error().message.find("not a usable serial port"), std::string::npos);

    SerialLink odd_baud(io.get_executor(), {file, 12345, 100ms, 1});
    EXPECT_EQ(odd_baud.open().error().code, Errc::invalid_argument);
}

// --- The port's reader: the thread that reads the tty for the loop ---------------------------
// A socket pair stands in for the tty: what the reader does with a descriptor is the same, and
// the test holds the other end.

class PortReaderTest : public ::testing::Test {
  protected:
    void SetUp() override {
        std::array<int, 2> ends{};
        ASSERT_EQ(::socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0, ends.data()),
                  0);
        port = ends[0];
        device = ends[1];
    }
    void TearDown() override {
        reader.reset();  // before the descriptor it reads is closed
        ::close(port);
        if (device >= 0) ::close(device);
    }
    void start() {
        reader = std::make_unique<PortReader>(io.get_executor(), port, [this] {
            ++wakeups;
            std::array<char, 64> buffer{};
            while (const auto n = reader->take(buffer))
                taken.append(buffer.data(), n);
        });
    }
    void send(std::string_view bytes) const {
        ASSERT_EQ(::write(device, bytes.data(), bytes.size()), static_cast<ssize_t>(bytes.size()));
    }
    bool reader_has_read(std::uint64_t count) const {
        return test::eventually([&] { return reader->bytes_read() >= count; },
                                10s * test::slowdown);
    }

    asio::io_context io;
    // The reader's posts are the loop's only work here: without this, the loop would stop.
    asio::executor_work_guard<asio::io_context::executor_type> work{io.get_executor()};
    int port = -1;
    int device = -1;
    std::unique_ptr<PortReader> reader;
    std::string taken;
    int wakeups = 0;
};

TEST_F(PortReaderTest, InputReachesTheLoopInOrder) {
    start();
    send("12");
    send("34\r");
    ASSERT_TRUE(test::run_until(
        io, [&] { return taken.size() >= 5; }, 10s * test::slowdown));
    EXPECT_EQ(taken, "1234\r");
    EXPECT_GE(wakeups, 1);
    EXPECT_FALSE(reader->error());
}

// The link's flush of stale input: what was read and not taken is gone, what comes after is not.
TEST_F(PortReaderTest, DiscardForgetsWhatWasReadAndNotTaken) {
    start();
    send("stale");
    ASSERT_TRUE(reader_has_read(5));
    reader->discard();
    send("new");
    ASSERT_TRUE(test::run_until(
        io, [&] { return taken.size() >= 3; }, 10s * test::slowdown));
    EXPECT_EQ(taken, "new");
}

// A loop that does not take what comes (it never should for long) costs a bounded queue; the
// excess is dropped and counted, never buffered without end.
TEST_F(PortReaderTest, InputBeyondTheQueuesBoundIsDroppedAndCounted) {
    start();
    const std::string flood(PortReader::max_queued + 100, '~');
    for (std::size_t sent = 0; sent < flood.size(); sent += 1000)
        send(std::string_view(flood).substr(sent, 1000));
    ASSERT_TRUE(reader_has_read(flood.size()));
    EXPECT_EQ(reader->bytes_dropped(), 100u);
    ASSERT_TRUE(test::run_until(
        io, [&] { return taken.size() >= PortReader::max_queued; }, 10s * test::slowdown));
    EXPECT_EQ(taken.size(), PortReader::max_queued);
}

TEST_F(PortReaderTest, TheOtherSideGoingAwayIsAnErrorForTheLoop) {
    start();
    ::close(device);
    device = -1;
    ASSERT_TRUE(test::run_until(
        io, [&] { return wakeups > 0; }, 10s * test::slowdown));
    EXPECT_TRUE(reader->error());
}

// What the tty does not take at once goes out as the other side makes room, in order.
TEST_F(PortReaderTest, WhatTheTtyDoesNotTakeIsSentAsRoomComes) {
    const int small = 4096;
    ASSERT_EQ(::setsockopt(port, SOL_SOCKET, SO_SNDBUF, &small, sizeof small), 0);
    start();
    std::string request(256 * 1024, '\0');
    for (std::size_t i = 0; i < request.size(); ++i)
        request[i] = static_cast<char>('a' + i % 26);
    std::string_view unsent = request;
    while (!unsent.empty()) {  // as the link writes: what the descriptor takes now
        const auto n = ::write(port, unsent.data(), unsent.size());
        if (n <= 0) break;
        unsent.remove_prefix(static_cast<std::size_t>(n));
    }
    ASSERT_FALSE(unsent.empty()) << "the socket took everything: nothing left to test";
    reader->send(unsent);
    EXPECT_GT(reader->unsent(), 0u);
    std::string received;
    ASSERT_TRUE(test::eventually(
        [&] {
            std::array<char, 4096> buffer{};
            const auto n = ::read(device, buffer.data(), buffer.size());
            if (n > 0) received.append(buffer.data(), static_cast<std::size_t>(n));
            return received.size() >= request.size();
        },
        10s * test::slowdown));
    EXPECT_EQ(received, request);
    EXPECT_EQ(reader->unsent(), 0u);
}

}  // namespace
}  // namespace ioport
