#include "daemon/base/file_descriptors.hpp"

#include <sys/resource.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include <fmt/format.h>

namespace ioport::daemon {

DescriptorRoom make_room_for_clients(std::size_t max_connections, std::size_t ports) {
    DescriptorRoom room;
    const auto own = reserved_descriptors + ports;
    const auto needed = static_cast<rlim_t>(max_connections + own);
    rlimit limit{};
    if (::getrlimit(RLIMIT_NOFILE, &limit) != 0) {
        room.clients = max_connections;
        room.shortfall = fmt::format("cannot read RLIMIT_NOFILE: {}", std::strerror(errno));
        return room;
    }
    std::string set_error;
    if (limit.rlim_cur != RLIM_INFINITY && limit.rlim_cur < needed) {
        rlimit raised = limit;
        raised.rlim_cur =
            limit.rlim_max == RLIM_INFINITY ? needed : std::min(needed, limit.rlim_max);
        if (raised.rlim_cur > limit.rlim_cur) {
            if (::setrlimit(RLIMIT_NOFILE, &raised) == 0) {
                limit = raised;
                room.raised = true;
            } else {
                set_error = fmt::format(" (raising it failed: {})", std::strerror(errno));
            }
        }
    }
    const auto soft = limit.rlim_cur == RLIM_INFINITY ? needed : limit.rlim_cur;
    room.soft_limit = static_cast<std::size_t>(soft);
    // A client that does not fit is refused, which takes a descriptor for a moment too: one of
    // the reserve.
    room.clients = std::clamp<std::size_t>(soft > own ? static_cast<std::size_t>(soft) - own : 1, 1,
                                           max_connections);
    if (room.clients < max_connections)
        room.shortfall = fmt::format(
            "max_connections {} needs {} file descriptors but the limit is {}{} (raise the hard "
            "limit: LimitNOFILE= in the systemd unit, or ulimit -Hn): at most {} clients are "
            "served, further ones are refused",
            max_connections, needed, soft, set_error, room.clients);
    return room;
}

}  // namespace ioport::daemon
