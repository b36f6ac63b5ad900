// Upper bounds on how long something may take are there to catch a hang or a stall, with room
// for a busy machine. Under ASan and UBSan every process of a test runs two to three times
// slower, and under qemu-user (a cross build's tests) slower still, so those builds stretch the
// bounds by `slowdown` (IOPORT_TEST_SLOWDOWN from tests/CMakeLists.txt); lower bounds and every
// check of values stay as they are.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <iostream>
#include <string>
#include <thread>

namespace ioport::test {

// The build's factor (tests/CMakeLists.txt): 1 natively, 3 under the sanitizers, more under
// qemu-user.
inline constexpr int slowdown = IOPORT_TEST_SLOWDOWN;

// A scenario's own clock: a storm that lasts so long, faults injected on a schedule. It waits
// for a time, not for a condition (there is none to wait for: use eventually() for those).
inline void pace_until(std::chrono::steady_clock::time_point when) {
    while (std::chrono::steady_clock::now() < when)
        std::this_thread::sleep_for(std::min<std::chrono::steady_clock::duration>(
            when - std::chrono::steady_clock::now(), std::chrono::milliseconds(5)));
}

// How long ago `start` was.
inline std::chrono::milliseconds since(std::chrono::steady_clock::time_point start) {
    return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() -
                                                                 start);
}

// A figure for the documentation: printed, and kept in the test's XML properties.
inline void figure(const std::string& name, const std::string& value) {
    ::testing::Test::RecordProperty(name, value);
    std::cout << "[ figure   ] " << name << ": " << value << "\n";
}

}  // namespace ioport::test
