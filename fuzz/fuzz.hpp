// What every fuzz target shares: libFuzzer's entry point and the invariant check.
//
// A target is built two ways (fuzz/CMakeLists.txt): with clang's libFuzzer, which calls
// LLVMFuzzerTestOneInput with inputs it generates, or as a plain program (replay_main.cpp) that
// calls it with the files of a corpus, so that every compiler and sanitizer build replays the
// committed corpus as a test.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <iostream>
#include <string_view>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace ioport::fuzz {

// A broken invariant is a finding: it aborts, as a sanitizer report does, so that libFuzzer
// keeps the input as a crash and a replay fails.
inline void check(bool holds, std::string_view invariant) {
    if (holds) return;
    std::cerr << "invariant broken: " << invariant << std::endl;
    std::abort();
}

}  // namespace ioport::fuzz
