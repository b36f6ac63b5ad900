#include "protocol/exchange.hpp"

namespace ioport {

Result<Exchange> make_exchange(ModuleAddress module, std::uint16_t output_value) {
    auto request = encode_request(module, output_value);
    if (!request) return Unexpected(request.error());
    return Exchange{module, std::move(*request), cr, reply_length(module.type)};
}

Exchange make_exchange(id2::Command command) {
    return Exchange{command, id2::encode_request(command), id2::lf, id2::reply_length(command)};
}

Result<Reading> decode(const Exchange& exchange, std::string_view frame) {
    if (const auto* module = std::get_if<ModuleAddress>(&exchange.target))
        return parse_reply(module->type, frame);
    const auto command = std::get<id2::Command>(exchange.target);
    auto value = id2::parse_reply(command, frame);
    if (!value) return Unexpected(value.error());
    Reading reading;
    if (command != id2::Command::reset) {
        reading.raw[0] = *value;
        reading.count = 1;
    }
    return reading;
}

std::string describe(const Target& target) {
    if (const auto* module = std::get_if<ModuleAddress>(&target)) return to_string(*module);
    return "ID-2 " + std::string(id2::name(std::get<id2::Command>(target)));
}

}  // namespace ioport
