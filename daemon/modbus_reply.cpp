#include "daemon/modbus_reply.hpp"

#include <algorithm>
#include <new>

namespace ioport::daemon {

UnitImage::UnitImage()
    : mapping_(modbus_mapping_new_start_address(
          0, gateway::coil_count, 0, gateway::discrete_input_count, 0,
          gateway::holding_register_count, 0, gateway::input_register_count)) {
    if (!mapping_) throw std::bad_alloc();
    auto* m = mapping_.get();
    tables_ = {{m->tab_bits, gateway::coil_count},
               {m->tab_input_bits, gateway::discrete_input_count},
               {m->tab_registers, gateway::holding_register_count},
               {m->tab_input_registers, gateway::input_register_count}};
}

Mapping scratch_mapping() {
    Mapping mapping(modbus_mapping_new(gateway::coil_count, 0, gateway::holding_register_count, 0));
    if (!mapping) throw std::bad_alloc();
    return mapping;
}

PaddedRequest::PaddedRequest(std::span<const std::uint8_t> adu)
    : length_(std::min(adu.size(), modbus::max_adu_length)) {
    std::copy_n(adu.begin(), length_, bytes_.begin());
}

int reply(modbus_t* context, const PaddedRequest& request, modbus_mapping_t* mapping) {
    return modbus_reply(context, request.bytes_.data(), static_cast<int>(request.length_), mapping);
}

int reply_exception(modbus_t* context, const PaddedRequest& request, modbus::Exception exception) {
    // libmodbus answers function + 0x80, which for a request function code of 0x80 or above
    // wraps to a byte without the exception bit (0xFF → 0x7F, a normal-looking response). It is
    // given a copy with the high bit cleared, so that the sum is the code with the bit set.
    auto bytes = request.bytes_;
    bytes[modbus::mbap_length] &= 0x7F;
    return modbus_reply_exception(context, bytes.data(), static_cast<unsigned>(exception));
}

}  // namespace ioport::daemon
