// The last ten minutes of an analog module's readings, for the status page's plots: one point
// per interval (the last reading in it), in a fixed ring, so that memory does not grow with
// uptime and a full bus of analog modules costs a fixed, small amount (see bench/README.md).
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>

namespace ioport::daemon {

class Trend {
  public:
    static constexpr std::chrono::seconds interval{5};
    static constexpr std::size_t capacity = 120;  // 10 minutes
    struct Point {
        std::int64_t time;                 // Unix seconds, the start of its interval
        std::array<std::uint16_t, 3> raw;  // the reading's words
    };

    // A good reading at `at`: a new point, or the newer value of this interval's point.
    void add(std::chrono::system_clock::time_point at, const std::array<std::uint16_t, 3>& raw) {
        const auto seconds =
            std::chrono::duration_cast<std::chrono::seconds>(at.time_since_epoch()).count();
        const std::int64_t start = seconds - seconds % interval.count();
        if (size_ > 0 && points_[(head_ + size_ - 1) % capacity].time == start) {
            points_[(head_ + size_ - 1) % capacity].raw = raw;
            return;
        }
        if (size_ < capacity) {
            points_[(head_ + size_++) % capacity] = {start, raw};
            return;
        }
        points_[head_] = {start, raw};
        head_ = (head_ + 1) % capacity;
    }
    std::size_t size() const { return size_; }
    // i = 0 is the oldest.
    const Point& operator[](std::size_t i) const { return points_[(head_ + i) % capacity]; }

  private:
    std::array<Point, capacity> points_{};
    std::size_t head_ = 0;
    std::size_t size_ = 0;
};

}  // namespace ioport::daemon
