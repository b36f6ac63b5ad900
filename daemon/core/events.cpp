#include "daemon/core/events.hpp"

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
    add({.kind = kind,
         .link = std::string(link),
         .module = std::string(module),
         .client = std::string(client),
         .text = std::move(text)});
}

void EventLog::add(Event event) {
    if (events_.size() == capacity) events_.pop_front();
    event.seq = next_seq_++;
    event.time = std::chrono::system_clock::now();
    events_.push_back(std::move(event));
}

}  // namespace ioport::daemon
