#include "daemon/events.hpp"

namespace ioport::daemon {

std::string_view to_string(EventKind kind) {
    switch (kind) {
        case EventKind::module_online:
            return "module_online";
        case EventKind::module_offline:
            return "module_offline";
        case EventKind::port_down:
            return "port_down";
        case EventKind::port_up:
            return "port_up";
        case EventKind::write:
            return "write";
        case EventKind::reload:
            return "reload";
        case EventKind::comm_loss:
            return "comm_loss";
        case EventKind::client_refused:
            return "client_refused";
    }
    return "unknown";
}

void EventLog::add(EventKind kind, std::string_view link, std::string_view module,
                   std::string_view client, std::string text) {
    if (events_.size() == capacity) events_.pop_front();
    events_.push_back({next_seq_++, std::chrono::system_clock::now(), kind, std::string(link),
                       std::string(module), std::string(client), std::move(text)});
}

}  // namespace ioport::daemon
