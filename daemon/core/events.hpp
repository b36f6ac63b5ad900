// What happened lately, for the status page: the last events of the links and the Modbus front
// (modules going on and off line, ports lost and back, client writes, reloads, communication
// loss, refused clients). The log has all of them too; this keeps the last few in memory, with
// the fields the page shows.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <string>
#include <string_view>

namespace ioport::daemon {

enum class EventKind {
    module_online,
    module_offline,
    port_down,
    port_up,
    write,
    reload,
    comm_loss,
    client_refused,
};
// "module_online", as in /api/v1/state.
std::string_view to_string(EventKind kind);

struct Event {
    std::uint64_t seq = 0;  // 1, 2, … since start: lets a reader tell new events from seen ones
    std::chrono::system_clock::time_point time{};
    EventKind kind = EventKind::reload;
    std::string link{};
    std::string module{};
    std::string client{};
    std::string text{};  // the log line's message
};

class EventLog {
  public:
    static constexpr std::size_t capacity = 100;

    void add(EventKind kind, std::string_view link, std::string_view module,
             std::string_view client, std::string text);
    // `event` as it happened now: its seq and time are given here.
    void add(Event event);
    // Oldest first.
    const std::deque<Event>& events() const { return events_; }

  private:
    std::deque<Event> events_;
    std::uint64_t next_seq_ = 1;
};

}  // namespace ioport::daemon
