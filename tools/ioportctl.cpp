#include <cstdlib>
#include <exception>
#include <iostream>
#include <string_view>
#include <vector>

#include "tools/ctl.hpp"

int main(int argc, char** argv) {
    try {
        const std::vector<std::string_view> args(argv + 1, argv + argc);
        const char* port = std::getenv("IOPORT_PORT");
        return ioport::ctl::run_command_line(args, port && *port ? port : "/dev/ttyUSB0", std::cout,
                                             std::cerr);
    } catch (const std::exception& e) {
        std::cerr << "ioportctl: internal error: " << e.what() << "\n";
        return 70;  // EX_SOFTWARE
    }
}
