// What a process has written, from /proc/PID/io: the bytes it handed to write() and its
// relatives (wchar), and the bytes the kernel sent to the block device on its behalf
// (write_bytes). The store's benchmarks count bytes written per record with it.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <fstream>
#include <string>

namespace ioport::bench {

struct ProcessIo {
    std::uint64_t wchar = 0;
    std::uint64_t write_bytes = 0;
};

inline ProcessIo process_io(pid_t pid) {
    ProcessIo io;
    std::ifstream file("/proc/" + std::to_string(pid) + "/io");
    std::string key;
    std::uint64_t value = 0;
    while (file >> key >> value) {
        if (key == "wchar:") io.wchar = value;
        if (key == "write_bytes:") io.write_bytes = value;
    }
    return io;
}

}  // namespace ioport::bench
