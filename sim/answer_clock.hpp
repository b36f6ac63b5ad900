// When the simulator's answers leave, against when its line model says they end.
//
// The simulator writes an answer when a timer set for the answer's modelled end expires, and a
// timer wakes its thread late: on the benchmark's KVM guest 35 µs in the median and 68 µs at
// p90, even with idle CPUs polling. Added to every answer, that alone is 4 % of a dim16 read at
// 115200 baud, and every master measured against the simulator looks that much slower than the
// line. So the timer is set early by the median of how late the answers have gone out, learnt
// one answer at a time: the answers then leave at their modelled end in the median, some a few
// µs early, some late. The errors that remain are kept, so that a benchmark can say how well the
// simulator kept time.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>

namespace ioport::sim {

// A histogram of answer errors (written − modelled end) in 1 µs buckets from −256 µs to
// +1791 µs; errors outside fall into the end buckets.
class AnswerErrors {
  public:
    void add(std::chrono::nanoseconds error);
    std::uint64_t count() const { return count_; }
    // The error at quantile q (0–1) to the µs; zero when there is none.
    std::chrono::microseconds quantile(double q) const;

  private:
    static constexpr int lowest_us = -256;
    std::array<std::uint32_t, 2048> buckets_{};
    std::uint64_t count_ = 0;
};

class AnswerClock {
  public:
    // How far ahead of an answer's modelled end to set its timer.
    std::chrono::nanoseconds advance() const { return advance_; }
    // An answer went out `error` after its modelled end (negative: before).
    void answered(std::chrono::nanoseconds error);
    const AnswerErrors& errors() const { return errors_; }
    void clear_errors() { errors_ = {}; }

    // The steps by which the advance follows the median (a sign-driven estimate, which one late
    // answer far out in the tail cannot drag), and the most it may reach: beyond that the delay is
    // no timer's, but a machine too busy to run the simulator, and no advance would be right.
    static constexpr std::chrono::nanoseconds step{500};
    static constexpr std::chrono::nanoseconds max_advance = std::chrono::microseconds{100};

  private:
    std::chrono::nanoseconds advance_{};
    AnswerErrors errors_;
};

}  // namespace ioport::sim
