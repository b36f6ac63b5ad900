#include "daemon/modbus/device_identity.hpp"

#include <algorithm>

namespace ioport::daemon {
namespace {

using modbus::DeviceObject;

constexpr std::size_t max_object_length = 64;

std::string printable_name(const std::string& name) {
    std::string text = name.substr(0, max_object_length);
    std::ranges::replace_if(
        text, [](char c) { return c < 0x20 || c > 0x7E; }, '?');
    return text;
}

}  // namespace

modbus::DeviceIdentity device_identity(const config::LinkConfig& link, std::string_view version) {
    modbus::DeviceIdentity identity = link.identity;
    const auto fill = [&](DeviceObject object, std::string_view value) {
        auto& text = identity[static_cast<std::size_t>(object)];
        if (text.empty()) text = value;
    };
    fill(DeviceObject::vendor_name, default_vendor_name);
    fill(DeviceObject::product_code, default_product_code);
    identity[static_cast<std::size_t>(DeviceObject::major_minor_revision)] = version;
    fill(DeviceObject::vendor_url, default_vendor_url);
    fill(DeviceObject::product_name, default_product_name);
    fill(DeviceObject::model_name,
         link.protocol == config::Protocol::id2 ? std::string_view("ID-2") : "ioport hub");
    fill(DeviceObject::user_application_name, printable_name(link.name));
    return identity;
}

}  // namespace ioport::daemon
