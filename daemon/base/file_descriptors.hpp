// File descriptors for the Modbus clients. Each client holds one, beside the serial ports and a
// few of ioportd's own. systemd starts services with a soft RLIMIT_NOFILE of 1024 (and a much
// higher hard limit), so a max_connections near 1000 or above would make accept() fail with
// EMFILE and leave clients waiting in the listen backlog, neither served nor refused.
#pragma once

#include <cstddef>
#include <optional>
#include <string>

namespace ioport::daemon {

// Standard streams, the journal and notify sockets, the event loop's own descriptors, the
// listener (two during a reload that moves it), the reply socket pair: 64 leaves ample room.
inline constexpr std::size_t reserved_descriptors = 64;

struct DescriptorRoom {
    std::size_t clients = 0;     // clients that fit under the limit, at most the asked number
    std::size_t soft_limit = 0;  // RLIMIT_NOFILE now
    bool raised = false;         // the soft limit was raised for this
    std::optional<std::string> shortfall;  // why fewer clients fit than asked, for the log
};

// Raises the soft RLIMIT_NOFILE (never above the hard limit, never lowers it) so that
// `max_connections` clients and `ports` serial ports fit beside the reserve.
DescriptorRoom make_room_for_clients(std::size_t max_connections, std::size_t ports);

}  // namespace ioport::daemon
