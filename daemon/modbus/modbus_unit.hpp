// One link as a Modbus unit (gateway.md §4): its register image, rendered from the core's read
// model, and the objects it answers Read Device Identification with.
//
// The image is a libmodbus mapping because libmodbus builds the read responses from one: kept
// here, the one place that answers Modbus, and updated by the link's change events as each value
// is stored, so a read costs what it did when the link wrote the image itself. Only the
// time-dependent registers (ages, the link's diagnostics, the front's traffic) are brought up to
// date when a request reads them.
#pragma once

#include <memory>

#include <modbus/modbus.h>

#include "daemon/core/link_scheduler.hpp"
#include "daemon/modbus/modbus_reply.hpp"
#include "protocol/device_identification.hpp"

namespace ioport::daemon {

// What a Modbus request answers for a write's outcome: nothing (confirmed), 04 (error ack),
// 06 (busy) or 0B.
std::optional<modbus::Exception> exception_of(WriteResult result);

class ModbusUnit {
  public:
    ModbusUnit(std::shared_ptr<LinkScheduler> link, gateway::WordOrder word_order);
    ModbusUnit(const ModbusUnit&) = delete;
    ModbusUnit& operator=(const ModbusUnit&) = delete;

    LinkScheduler& link() const { return *link_; }
    const std::shared_ptr<LinkScheduler>& link_ptr() const { return link_; }
    gateway::WordOrder word_order() const { return word_order_; }
    const modbus::DeviceIdentity& identity() const { return identity_; }
    // The image, with the link's diagnostics (1000-1009 and the ages) brought up to date when
    // `diagnostics`.
    modbus_mapping_t* image(bool diagnostics);
    const gateway::Tables& tables() const { return image_.tables(); }

  private:
    void store(const ModuleState& module);

    std::shared_ptr<LinkScheduler> link_;
    gateway::WordOrder word_order_;
    modbus::DeviceIdentity identity_;
    UnitImage image_;
    EventBus::Subscription subscription_;
};

}  // namespace ioport::daemon
