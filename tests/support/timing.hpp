// Upper bounds on how long something may take are there to catch a hang or a stall, with room
// for a busy machine. Under ASan and UBSan every process of a test runs two to three times
// slower, so the sanitizer build stretches those bounds by `slowdown`; lower bounds and every
// check of values stay as they are.
#pragma once

namespace ioport::test {

#if defined(__SANITIZE_ADDRESS__)
inline constexpr int slowdown = 3;
#else
inline constexpr int slowdown = 1;
#endif

}  // namespace ioport::test
