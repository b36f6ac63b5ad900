// The standard process metrics of Prometheus' client libraries (process_cpu_seconds_total,
// process_resident_memory_bytes, process_open_fds, process_start_time_seconds), from /proc.
#pragma once

#include <cstdint>
#include <optional>
#include <string_view>

namespace ioport::daemon {

struct ProcessStats {
    double cpu_seconds = 0;  // user + system
    std::uint64_t resident_bytes = 0;
    std::uint64_t open_fds = 0;
    double start_time_seconds = 0;  // Unix time
};

// From the text of /proc/self/stat (proc(5)): utime, stime, starttime and rss, given the
// clock ticks per second, the page size and the boot time (Unix seconds). nullopt when the
// text is not what the kernel writes.
std::optional<ProcessStats> parse_proc_stat(std::string_view stat, long ticks_per_second,
                                            long page_size, double boot_time);

// This process, now; what cannot be read stays 0. Only /proc/self is read: the packaged unit's
// ProcSubset=pid hides /proc/stat, so the boot time is the difference of the realtime and boot
// clocks instead.
ProcessStats read_process_stats();

}  // namespace ioport::daemon
