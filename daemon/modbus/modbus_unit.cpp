#include "daemon/modbus/modbus_unit.hpp"

#include <algorithm>

#include "daemon/modbus/device_identity.hpp"

namespace ioport::daemon {

using gateway::ModuleStatus;
using modbus::Exception;

std::optional<Exception> exception_of(WriteResult result) {
    switch (result) {
        case WriteResult::confirmed:
            return std::nullopt;
        case WriteResult::error_ack:
            return Exception::server_device_failure;
        case WriteResult::busy:
            return Exception::server_device_busy;
        case WriteResult::no_answer:
        case WriteResult::link_down:
        case WriteResult::dropped:
            break;
    }
    return Exception::gateway_target_failed;
}

ModbusUnit::ModbusUnit(std::shared_ptr<LinkScheduler> link, gateway::WordOrder word_order)
    : link_(std::move(link)),
      word_order_(word_order),
      identity_(device_identity(link_->config(), IOPORTD_VERSION)) {
    // A unit made for a link that is running already (a reload) starts from what it knows.
    for (const auto& module : link_->modules())
        store(module);
    (void)image(true);
    // The image follows the link's values as they are stored; the diagnostics are made per
    // request, by image().
    subscription_ = link_->bus().subscribe([this](const BusEvent& event) {
        if (link_of(event) != link_.get()) return;
        if (const auto* changed = std::get_if<ValuesChanged>(&event)) {
            store(*changed->module);
        } else if (std::holds_alternative<TagsChanged>(event)) {  // rescaled: every float again
            for (const auto& module : link_->modules())
                store(module);
        }
    });
}

void ModbusUnit::store(const ModuleState& module) {
    const auto& tables = image_.tables();
    if (!module.address) {  // the ID-2
        if (module.stop) gateway::store_id2(tables, id2::Command::stop_input, *module.stop ? 1 : 0);
        if (module.count) gateway::store_id2(tables, id2::Command::count, *module.count);
        return;
    }
    if (module.reading)
        gateway::store_reading(tables, *module.address, *module.reading, word_order_,
                               module.values);
    if (module.output) gateway::store_output(tables, *module.address, *module.output);
}

modbus_mapping_t* ModbusUnit::image(bool diagnostics) {
    if (!diagnostics) return image_.mapping();
    const auto& link = *link_;
    const auto& status = link.state().status;
    const auto now = Clock::now();
    gateway::Diagnostics d;
    const bool all_online = std::all_of(status.begin(), status.end(), [](ModuleStatus s) {
        return s == ModuleStatus::not_configured || s == ModuleStatus::online;
    });
    d.link_state = !link.port_open() ? gateway::LinkState::port_not_open
                   : all_online      ? gateway::LinkState::all_online
                                     : gateway::LinkState::some_offline;
    d.last_cycle = link.last_cycle();
    d.cycles = link.cycles();
    d.transactions_ok = link.counters().transactions_ok;
    d.transactions_failed = link.counters().transactions_failed();
    d.opens = link.counters().opens;
    d.status = status;
    d.age_ms.fill(0xFFFFFFFF);
    for (const auto& module : link.modules()) {
        if (!module.last_good) continue;
        d.age_ms[static_cast<std::size_t>(module.slot)] =
            static_cast<std::uint32_t>(std::min<long long>(
                std::chrono::duration_cast<std::chrono::milliseconds>(now - *module.last_good)
                    .count(),
                0xFFFFFFFF));
    }
    gateway::store_diagnostics(image_.tables(), d, word_order_);
    return image_.mapping();
}

}  // namespace ioport::daemon
