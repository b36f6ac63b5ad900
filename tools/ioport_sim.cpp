#include <exception>
#include <iostream>
#include <string_view>
#include <vector>

#include "tools/sim_cli.hpp"

int main(int argc, char** argv) {
    try {
        const std::vector<std::string_view> args(argv + 1, argv + argc);
        return ioport::sim_cli::run_command_line(args, std::cout, std::cerr);
    } catch (const std::exception& e) {
        std::cerr << "ioport-sim: internal error: " << e.what() << "\n";
        return 70;  // EX_SOFTWARE
    }
}
