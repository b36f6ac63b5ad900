// The main() of a fuzz target built without libFuzzer: runs the target once on each file named,
// and on each regular file of each directory named (in name order, so a failure is
// reproducible). A finding aborts, so the exit status tells whether the corpus replays clean.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <vector>

#include "fuzz/fuzz.hpp"

namespace {

namespace fs = std::filesystem;

std::vector<fs::path> inputs(const fs::path& argument) {
    if (!fs::is_directory(argument)) return {argument};
    std::vector<fs::path> files;
    for (const auto& entry : fs::directory_iterator(argument))
        if (entry.is_regular_file()) files.push_back(entry.path());
    std::sort(files.begin(), files.end());
    return files;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::cerr << "usage: " << argv[0] << " FILE|DIRECTORY...\n";
        return 2;
    }
    std::size_t replayed = 0;
    for (int i = 1; i < argc; ++i) {
        if (!fs::exists(argv[i])) {
            std::cerr << argv[i] << ": no such file or directory\n";
            return 2;
        }
        for (const auto& path : inputs(argv[i])) {
            std::ifstream file(path, std::ios::binary);
            const std::vector<std::uint8_t> data((std::istreambuf_iterator<char>(file)),
                                                 std::istreambuf_iterator<char>());
            LLVMFuzzerTestOneInput(data.data(), data.size());
            ++replayed;
        }
    }
    // An empty corpus would make the replay test pass without testing anything.
    std::cout << replayed << " inputs replayed\n";
    return replayed > 0 ? 0 : 1;
}
