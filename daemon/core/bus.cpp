#include "daemon/core/bus.hpp"

#include <algorithm>
#include <type_traits>

#include "daemon/core/link_scheduler.hpp"

namespace ioport::daemon {

const LinkScheduler* link_of(const BusEvent& event) {
    return std::visit(
        [](const auto& e) -> const LinkScheduler* {
            if constexpr (std::is_same_v<std::decay_t<decltype(e)>, Note>)
                return nullptr;
            else
                return e.link;
        },
        event);
}

EventBus::Subscription EventBus::subscribe(Handler handler) {
    auto subscription = std::make_shared<const Handler>(std::move(handler));
    handlers_.push_back(subscription);
    return subscription;
}

void EventBus::publish(const BusEvent& event) {
    std::erase_if(handlers_, [](const auto& handler) { return handler.expired(); });
    // By index: a handler may subscribe while called; the call holds its own handler alive.
    for (std::size_t i = 0; i < handlers_.size(); ++i)
        if (const auto handler = handlers_[i].lock()) (*handler)(event);
}

void record(EventLog& log, const BusEvent& event) {
    std::visit(
        [&](const auto& e) {
            using E = std::decay_t<decltype(e)>;
            if constexpr (std::is_same_v<E, StatusChanged>) {
                if (e.text.empty()) return;
                log.add(e.after == gateway::ModuleStatus::online ? EventKind::module_online
                                                                 : EventKind::module_offline,
                        e.link->config().name, e.module->name, {}, std::string(e.text));
            } else if constexpr (std::is_same_v<E, PortChanged>) {
                log.add(e.open ? EventKind::port_up : EventKind::port_down, e.link->config().name,
                        {}, {}, std::string(e.text));
            } else if constexpr (std::is_same_v<E, WriteAudited>) {
                log.add(EventKind::write, e.link->config().name, {}, e.origin->client,
                        std::string(e.text));
            } else if constexpr (std::is_same_v<E, Note>) {
                log.add(e.kind, e.link, e.module, e.client, std::string(e.text));
            } else {
                static_assert(std::is_same_v<E, ValuesChanged> || std::is_same_v<E, TagsChanged>);
            }
        },
        event);
}

}  // namespace ioport::daemon
