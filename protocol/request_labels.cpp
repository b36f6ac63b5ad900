#include "protocol/request_labels.hpp"

#include "protocol/device_identification.hpp"
#include "protocol/modbus.hpp"

namespace ioport::gateway {
namespace {

constexpr int max_unit_id = 247;  // Modbus: 248..255 are reserved, 0 is broadcast

}  // namespace

int unit_label(int unit_id) {
    return unit_id >= 1 && unit_id <= max_unit_id ? unit_id : other_label;
}

int function_label(std::uint8_t function) {
    if (function == modbus::encapsulated_interface_transport) return function;
    switch (static_cast<modbus::Function>(function)) {
        case modbus::Function::read_coils:
        case modbus::Function::read_discrete_inputs:
        case modbus::Function::read_holding_registers:
        case modbus::Function::read_input_registers:
        case modbus::Function::write_single_coil:
        case modbus::Function::write_single_register:
        case modbus::Function::write_multiple_coils:
        case modbus::Function::write_multiple_registers:
        case modbus::Function::read_write_multiple_registers:
            return function;
    }
    return other_label;
}

int exception_label(std::uint8_t code) {
    switch (static_cast<modbus::Exception>(code)) {
        case modbus::Exception::illegal_function:
        case modbus::Exception::illegal_data_address:
        case modbus::Exception::illegal_data_value:
        case modbus::Exception::server_device_failure:
        case modbus::Exception::server_device_busy:
        case modbus::Exception::gateway_path_unavailable:
        case modbus::Exception::gateway_target_failed:
            return code;
    }
    return other_label;
}

std::string label_text(int label) {
    return label == other_label ? "other" : std::to_string(label);
}

void RequestCounts::count(int unit_id, std::uint8_t function,
                          std::span<const std::uint8_t> response) {
    if (unit_id >= 0)
        count_response(traffic_[static_cast<std::size_t>(unit_id) & 0xFF], function, response);
    const int unit = unit_label(unit_id);
    ++requests_[{unit, function_label(function)}];
    if (response.size() >= 2 && (response[0] & 0x80U) != 0)
        ++exceptions_[{unit, exception_label(response[1])}];
}

}  // namespace ioport::gateway
