// What a unit answers to Read Device Identification (FC 43 / MEI 14, gateway.md §5.2): the
// link's `identity:` where it sets an object, ioportd's own values elsewhere.
#pragma once

#include "config/gateway_config.hpp"
#include "protocol/device_identification.hpp"

namespace ioport::daemon {

inline constexpr std::string_view default_vendor_name = "ioportd developers";
inline constexpr std::string_view default_product_code = "ioportd";
// The manual on the box itself: the one address of ioportd's that every installation has.
inline constexpr std::string_view default_vendor_url = "man:ioportd(8)";
inline constexpr std::string_view default_product_name = "ioportd serial-to-Modbus gateway";

// MajorMinorRevision is `version`; ModelName defaults to "ioport hub" or "ID-2" by protocol,
// UserApplicationName to the link's name (cut to the 64 printable characters an object holds).
modbus::DeviceIdentity device_identity(const config::LinkConfig& link, std::string_view version);

}  // namespace ioport::daemon
