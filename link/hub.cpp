#include "link/hub.hpp"

#include <fmt/format.h>

namespace ioport {

template <class T>
Result<T> Hub::record(Result<T> result) const {
    if (!result) last_error_ = result.error().message;
    return result;
}

Result<> Hub::open(const std::string& device, HubOptions options) {
    link_.emplace(LinkSettings{device, options.baud, options.timeout, options.retries});
    readings_.fill(std::nullopt);
    return record(link_->open());
}

void Hub::close() {
    if (link_) link_->close();
}

Result<ModuleAddress> Hub::address(ModuleType type, int number) const {
    if (number < 0 || number >= modules_per_type)
        return record<ModuleAddress>(
            fail(Errc::invalid_argument,
                 fmt::format("{} module number {} is out of range 0-7", name(type), number)));
    return ModuleAddress{type, static_cast<std::uint8_t>(number)};
}

Result<> Hub::update(ModuleAddress module) {
    if (!link_)
        return record<void>(fail(Errc::port_closed, "the hub is not open: call open() first"));
    auto exchange = make_exchange(module, staged_[static_cast<std::size_t>(slot(module))]);
    if (!exchange) return record<void>(Unexpected(exchange.error()));
    auto reading = link_->transact(*exchange);
    if (!reading) return record<void>(Unexpected(reading.error()));
    if (!is_output(module.type)) readings_[static_cast<std::size_t>(slot(module))] = *reading;
    return {};
}

Result<> Hub::update(std::string_view module_name, int number) {
    const auto type = module_type_from_name(module_name);
    if (!type)
        return record<void>(fail(Errc::invalid_argument,
                                 fmt::format("unknown module type '{}': use dim16 dom16 acm3p "
                                             "acm3c lim16 rgbdm dccim dcvim mux8m",
                                             module_name)));
    const auto module = address(*type, number);
    if (!module) return Unexpected(module.error());
    return update(*module);
}

Result<Reading> Hub::reading(ModuleAddress module) const {
    const auto& reading = readings_[static_cast<std::size_t>(slot(module))];
    if (!reading)
        return record<Reading>(
            fail(Errc::invalid_argument,
                 fmt::format("{} has not been read: call update() first", to_string(module))));
    return *reading;
}

Result<bool> Hub::input_bit(ModuleType type, int number, int input) const {
    const auto module = address(type, number);
    if (!module) return Unexpected(module.error());
    if (input < 0 || input > 15)
        return record<bool>(
            fail(Errc::invalid_argument,
                 fmt::format("{} input {} is out of range 0-15", name(type), input)));
    const auto last = reading(*module);
    if (!last) return Unexpected(last.error());
    return (last->raw[0] >> input & 1U) != 0;
}

Result<double> Hub::channel(ModuleType type, int number, int channel) const {
    const auto module = address(type, number);
    if (!module) return Unexpected(module.error());
    if (channel < 0 || channel >= reply_words(type))
        return record<double>(
            fail(Errc::invalid_argument, fmt::format("{} channel {} is out of range 0-{}",
                                                     name(type), channel, reply_words(type) - 1)));
    const auto last = reading(*module);
    if (!last) return Unexpected(last.error());
    return engineering_value(type, last->raw[static_cast<std::size_t>(channel)]);
}

Result<bool> Hub::dim16(int number, int input) const {
    return input_bit(ModuleType::dim16, number, input);
}
Result<bool> Hub::lim16(int number, int input) const {
    return input_bit(ModuleType::lim16, number, input);
}
Result<double> Hub::acm3p(int number, int ch) const {
    return channel(ModuleType::acm3p, number, ch);
}
Result<double> Hub::acm3c(int number, int ch) const {
    return channel(ModuleType::acm3c, number, ch);
}
Result<double> Hub::dccim(int number) const {
    return channel(ModuleType::dccim, number, 0);
}
Result<double> Hub::dcvim(int number) const {
    return channel(ModuleType::dcvim, number, 0);
}

Result<> Hub::set_dom16(int number, int output, bool on) {
    const auto module = address(ModuleType::dom16, number);
    if (!module) return Unexpected(module.error());
    if (output < 0 || output > 15)
        return record<void>(fail(Errc::invalid_argument,
                                 fmt::format("dom16 output {} is out of range 0-15", output)));
    auto& word = staged_[static_cast<std::size_t>(slot(*module))];
    const auto bit = static_cast<std::uint16_t>(1U << output);
    word = static_cast<std::uint16_t>(on ? word | bit : word & ~bit);
    return {};
}

Result<> Hub::set_dom16_word(int number, std::uint16_t word) {
    const auto module = address(ModuleType::dom16, number);
    if (!module) return Unexpected(module.error());
    staged_[static_cast<std::size_t>(slot(*module))] = word;
    return {};
}

Result<> Hub::set_rgbdm(int number, Colour colour) {
    const auto module = address(ModuleType::rgbdm, number);
    if (!module) return Unexpected(module.error());
    staged_[static_cast<std::size_t>(slot(*module))] = static_cast<std::uint16_t>(colour);
    return {};
}

Result<> Hub::set_mux8m(int number, int pos, int neg) {
    const auto module = address(ModuleType::mux8m, number);
    if (!module) return Unexpected(module.error());
    if (pos < 0 || pos >= mux_test_points || neg < 0 || neg >= mux_test_points)
        return record<void>(
            fail(Errc::invalid_argument,
                 fmt::format("mux8m test points {} and {}: each must be 0-7", pos, neg)));
    staged_[static_cast<std::size_t>(slot(*module))] =
        MuxSetting{static_cast<std::uint8_t>(pos), static_cast<std::uint8_t>(neg)}.value();
    return {};
}

std::uint16_t Hub::staged(ModuleAddress module) const {
    return staged_[static_cast<std::size_t>(slot(module))];
}

}  // namespace ioport
