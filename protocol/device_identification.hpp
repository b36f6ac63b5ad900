// Read Device Identification, Modbus function 43 / MEI type 14 (Modbus Application Protocol
// v1.1b3 §6.21), as pure functions over bytes: a request PDU and a unit's objects in, the
// response PDU or the exception out. ioportd serves conformity level 0x82: the basic (0x00-0x02)
// and regular (0x03-0x06) objects, by stream and by individual access; it has no extended ones.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "protocol/modbus.hpp"

namespace ioport::modbus {

inline constexpr std::uint8_t encapsulated_interface_transport = 0x2B;  // function 43
inline constexpr std::uint8_t read_device_identification_mei = 0x0E;    // MEI type 14
inline constexpr std::uint8_t conformity_level = 0x82;  // regular, stream and individual access

// Object ids 0x00-0x06.
enum class DeviceObject : std::uint8_t {
    vendor_name,
    product_code,
    major_minor_revision,
    vendor_url,
    product_name,
    model_name,
    user_application_name,
};
inline constexpr std::size_t device_object_count = 7;
// A unit's objects, by object id; each 1-64 printable ASCII characters (the configuration
// checks), so that any one of them fits a response.
using DeviceIdentity = std::array<std::string, device_object_count>;

// The normal response PDU (function code first) to the request PDU `pdu` (function code 43
// first), or the exception: 01 for a MEI type other than 14, 03 for a PDU that is not 4 bytes or
// a Read Device ID code other than 01-04, 02 for an object id that individual access (04) does
// not know. Stream access (01 basic, 02 regular, 03 extended, which is the regular here) starts
// at the requested object, or at 0x00 when it is not one of the category's; objects that do not
// fit one response are announced with "more follows" and the next object id.
Expected<std::vector<std::uint8_t>, Exception> read_device_identification(
    std::span<const std::uint8_t> pdu, const DeviceIdentity& identity);

}  // namespace ioport::modbus
