#include "daemon/http/process_stats.hpp"

#include <time.h>
#include <unistd.h>

#include <charconv>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace ioport::daemon {
namespace {

std::optional<std::uint64_t> number(std::string_view text) {
    std::uint64_t value = 0;
    const auto* end = text.data() + text.size();
    const auto [at, ec] = std::from_chars(text.data(), end, value);
    if (ec != std::errc() || at != end) return std::nullopt;
    return value;
}

std::string read_file(const char* path) {
    std::ifstream file(path);
    return {std::istreambuf_iterator<char>(file), std::istreambuf_iterator<char>()};
}

}  // namespace

std::optional<ProcessStats> parse_proc_stat(std::string_view stat, long ticks_per_second,
                                            long page_size, double boot_time) {
    // "pid (comm) state ppid …": comm may hold spaces and parentheses, so fields are counted
    // from the last ')', after which comes field 3 (state).
    const auto close = stat.rfind(')');
    if (close == std::string_view::npos || ticks_per_second <= 0) return std::nullopt;
    std::string_view rest = stat.substr(close + 1);
    // Fields 3.. in order; we need 14 (utime), 15 (stime), 22 (starttime), 24 (rss).
    std::optional<std::uint64_t> utime, stime, starttime, rss;
    int field = 2;
    while (!rest.empty()) {
        const auto start = rest.find_first_not_of(' ');
        if (start == std::string_view::npos) break;
        rest.remove_prefix(start);
        const auto end = std::min(rest.find_first_of(" \n"), rest.size());
        const auto token = rest.substr(0, end);
        rest.remove_prefix(end == rest.size() ? end : end + 1);
        switch (++field) {
            case 14:
                utime = number(token);
                break;
            case 15:
                stime = number(token);
                break;
            case 22:
                starttime = number(token);
                break;
            case 24:
                rss = number(token);
                break;
            default:
                break;
        }
        if (field == 24) break;
    }
    if (!utime || !stime || !starttime || !rss) return std::nullopt;
    const auto ticks = static_cast<double>(ticks_per_second);
    return ProcessStats{static_cast<double>(*utime + *stime) / ticks,
                        *rss * static_cast<std::uint64_t>(page_size), 0,
                        boot_time + static_cast<double>(*starttime) / ticks};
}

ProcessStats read_process_stats() {
    timespec realtime{};
    timespec boottime{};
    ::clock_gettime(CLOCK_REALTIME, &realtime);
    ::clock_gettime(CLOCK_BOOTTIME, &boottime);
    const auto seconds = [](const timespec& t) {
        return static_cast<double>(t.tv_sec) + static_cast<double>(t.tv_nsec) / 1e9;
    };
    const double boot_time = seconds(realtime) - seconds(boottime);
    auto stats = parse_proc_stat(read_file("/proc/self/stat"), ::sysconf(_SC_CLK_TCK),
                                 ::sysconf(_SC_PAGESIZE), boot_time)
                     .value_or(ProcessStats{});
    std::error_code ec;
    for (std::filesystem::directory_iterator it("/proc/self/fd", ec), end; !ec && it != end;
         it.increment(ec))
        ++stats.open_fds;
    return stats;
}

}  // namespace ioport::daemon
