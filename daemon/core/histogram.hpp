// A Prometheus histogram: cumulative counts of observations at or under each bound, their sum
// and count. Observed where the event happens (a few compares and adds), rendered on scrape.
#pragma once

#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

namespace ioport::daemon {

class Histogram {
  public:
    // `bounds`: ascending upper bounds, in the family's base unit; +Inf is implied.
    explicit Histogram(std::span<const double> bounds)
        : bounds_(bounds), counts_(bounds.size(), 0) {}

    void observe(double value) {
        // Counts are per bucket here and made cumulative on rendering: one add per observation.
        const auto at = std::lower_bound(bounds_.begin(), bounds_.end(), value);
        if (at != bounds_.end()) ++counts_[static_cast<std::size_t>(at - bounds_.begin())];
        sum_ += value;
        ++count_;
    }
    std::span<const double> bounds() const { return bounds_; }
    // Observations at or under bounds()[i].
    std::uint64_t cumulative(std::size_t i) const {
        std::uint64_t total = 0;
        for (std::size_t j = 0; j <= i; ++j)
            total += counts_[j];
        return total;
    }
    double sum() const { return sum_; }
    std::uint64_t count() const { return count_; }

  private:
    std::span<const double> bounds_;
    std::vector<std::uint64_t> counts_;
    double sum_ = 0;
    std::uint64_t count_ = 0;
};

}  // namespace ioport::daemon
