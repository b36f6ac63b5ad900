#pragma once

// The programs a test or benchmark starts, and the source tree, are found from the program that
// runs: the build gives each as a path relative to that program's directory
// (`path_from_programs` in CMakeLists.txt). The text compiled in is then the same in every clone
// of the repository, so that ccache compiles the test programs once for all clones on a machine
// (CI's clone after a session's), as it does the rest.

#include <filesystem>
#include <string>
#include <string_view>

namespace ioport::test {

inline std::string beside_program(std::string_view relative) {
    std::error_code ec;
    // qemu-user answers for the emulated program.
    const auto self = std::filesystem::read_symlink("/proc/self/exe", ec);
    const auto directory = ec ? std::filesystem::current_path() : self.parent_path();
    return (directory / relative).lexically_normal().string();
}

}  // namespace ioport::test
