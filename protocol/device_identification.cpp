#include "protocol/device_identification.hpp"

namespace ioport::modbus {
namespace {

// A response PDU is at most 253 bytes; its header takes 7 (function, MEI type, Read Device ID
// code, conformity level, more follows, next object id, number of objects).
constexpr std::size_t max_pdu = 253;
constexpr std::uint8_t more_follows = 0xFF;

enum class Access : std::uint8_t { basic = 1, regular = 2, extended = 3, individual = 4 };

// The last object id a stream of this category reaches.
std::size_t last_object(Access access) {
    switch (access) {
        case Access::basic:
            return static_cast<std::size_t>(DeviceObject::major_minor_revision);
        case Access::regular:
        case Access::extended:  // there are no extended objects: the regular ones
        case Access::individual:
            return device_object_count - 1;
    }
    return device_object_count - 1;
}

void append_object(std::vector<std::uint8_t>& pdu, std::size_t id, const std::string& value) {
    pdu.push_back(static_cast<std::uint8_t>(id));
    pdu.push_back(static_cast<std::uint8_t>(value.size()));
    pdu.insert(pdu.end(), value.begin(), value.end());
}

}  // namespace

Expected<std::vector<std::uint8_t>, Exception> read_device_identification(
    std::span<const std::uint8_t> pdu, const DeviceIdentity& identity) {
    if (pdu.size() < 2 || pdu[1] != read_device_identification_mei)
        return Unexpected(Exception::illegal_function);
    if (pdu.size() != 4 || pdu[2] < 1 || pdu[2] > 4)
        return Unexpected(Exception::illegal_data_value);
    const auto access = static_cast<Access>(pdu[2]);
    const std::size_t requested = pdu[3];
    std::vector<std::uint8_t> response{encapsulated_interface_transport,
                                       read_device_identification_mei,
                                       pdu[2],
                                       conformity_level,
                                       0x00,  // more follows
                                       0x00,  // next object id
                                       0};    // number of objects
    response.reserve(max_pdu);
    if (access == Access::individual) {
        if (requested >= device_object_count) return Unexpected(Exception::illegal_data_address);
        append_object(response, requested, identity[requested]);
        response[6] = 1;
        return response;
    }
    const auto last = last_object(access);
    std::size_t id = requested <= last ? requested : 0;  // not of this category: from the start
    for (; id <= last; ++id) {
        if (response.size() + 2 + identity[id].size() > max_pdu) {
            response[4] = more_follows;
            response[5] = static_cast<std::uint8_t>(id);
            break;
        }
        append_object(response, id, identity[id]);
        ++response[6];
    }
    return response;
}

}  // namespace ioport::modbus
