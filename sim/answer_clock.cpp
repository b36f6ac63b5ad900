#include "sim/answer_clock.hpp"

#include <algorithm>
#include <cmath>

namespace ioport::sim {

void AnswerErrors::add(std::chrono::nanoseconds error) {
    const long long us = std::chrono::floor<std::chrono::microseconds>(error).count();
    const auto last = static_cast<long long>(buckets_.size()) - 1;
    ++buckets_[static_cast<std::size_t>(std::clamp(us - lowest_us, 0LL, last))];
    ++count_;
}

std::chrono::microseconds AnswerErrors::quantile(double q) const {
    if (count_ == 0) return {};
    // The nearest-rank definition: the smallest error with at least q of all at or below it.
    const auto rank = std::max<std::uint64_t>(
        1, static_cast<std::uint64_t>(
               std::ceil(std::clamp(q, 0.0, 1.0) * static_cast<double>(count_))));
    std::uint64_t seen = 0;
    for (std::size_t i = 0; i < buckets_.size(); ++i) {
        seen += buckets_[i];
        if (seen >= rank) return std::chrono::microseconds{static_cast<long long>(i) + lowest_us};
    }
    return std::chrono::microseconds{static_cast<long long>(buckets_.size()) - 1 + lowest_us};
}

void AnswerClock::answered(std::chrono::nanoseconds error) {
    errors_.add(error);
    if (error > std::chrono::nanoseconds::zero())
        advance_ = std::min(advance_ + step, max_advance);
    else if (error < std::chrono::nanoseconds::zero())
        advance_ = std::max(advance_ - step, std::chrono::nanoseconds::zero());
}

}  // namespace ioport::sim
