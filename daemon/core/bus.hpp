// The gateway's one event bus: what happened, with what changed, told on the loop the moment it
// happens to every subscriber. The links publish what their modules and ports do and every
// write's outcome; the outputs publish what they refuse; the gateway its reloads and
// communication losses. Subscribers are the outputs (each its own links' changes) and the event
// log the status page shows, a subscriber like any other (record()).
//
// An event points into the read model (the link, the module, the write's origin) and its texts
// are views: both are valid for the call only. A subscriber must not block; it may compare,
// store and publish. Each subscription has its own place: dropping it ends its calls and no
// other's (a node replaced by a reload may outlive its successor's subscriptions while a command
// of its own finishes).
#pragma once

#include <functional>
#include <memory>
#include <string_view>
#include <variant>
#include <vector>

#include "daemon/core/events.hpp"
#include "daemon/core/model.hpp"

namespace ioport::daemon {

class LinkScheduler;

// A module's reading or confirmed output was stored: module->values are the new ones.
struct ValuesChanged {
    const LinkScheduler* link;
    const ModuleState* module;
};
// A module's status changed. `text`: the log line when it went online or offline, else empty.
struct StatusChanged {
    const LinkScheduler* link;
    const ModuleState* module;
    gateway::ModuleStatus before;
    gateway::ModuleStatus after;
    std::string_view text;
};
// The link's port opened, or was lost (every polled module's status with it).
struct PortChanged {
    const LinkScheduler* link;
    bool open;
    std::string_view text;  // the log line
};
// A write reached the link and its outcome is known: audited, in the origin's words.
struct WriteAudited {
    const LinkScheduler* link;
    const WriteOrigin* origin;
    WriteResult result;
    std::string_view text;  // the audit line
};
// A reload changed the link's names, units or scales: every module's values are made anew.
struct TagsChanged {
    const LinkScheduler* link;
};
// What else happened that the event log keeps: a reload, a communication loss, a client
// refused, a command refused.
struct Note {
    EventKind kind;
    std::string_view link{};
    std::string_view module{};
    std::string_view client{};
    std::string_view text{};
};
using BusEvent =
    std::variant<ValuesChanged, StatusChanged, PortChanged, WriteAudited, TagsChanged, Note>;

// The link an event is of; null for a Note.
const LinkScheduler* link_of(const BusEvent& event);

class EventBus {
  public:
    using Handler = std::function<void(const BusEvent& event)>;
    using Subscription = std::shared_ptr<const Handler>;

    [[nodiscard]] Subscription subscribe(Handler handler);
    void publish(const BusEvent& event);

  private:
    std::vector<std::weak_ptr<const Handler>> handlers_;
};

// The event log's subscription: an entry for every event a person would want on the status page
// (a module online or offline, a port lost or back, an audited write, and every Note).
void record(EventLog& log, const BusEvent& event);

}  // namespace ioport::daemon
