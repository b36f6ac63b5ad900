// Fuzz target: replies from an ioport hub, as the gateway receives them, and requests to one, as
// the simulator does.
//
// Input: byte 0 chooses the module (type = byte % 9, number = byte / 9 % 8), byte 1 the size of
// the serial reads (1 + byte % 64), the rest is what arrives on the line. Every frame is decoded
// as the reply to that module's transaction (decode(), as SerialLink::transact does) and parsed
// as a request to a module (parse_request(), as the simulator's DeviceModel does), each result
// checked against the format of protocol.md §1, worked out here independently.
#include <algorithm>
#include <cctype>
#include <cstdint>
#include <string>
#include <string_view>

#include "fuzz/fuzz.hpp"
#include "fuzz/line_frames.hpp"
#include "protocol/exchange.hpp"
#include "protocol/ioport.hpp"

namespace ioport::fuzz {
namespace {

bool all_hex(std::string_view text) {
    return std::all_of(text.begin(), text.end(),
                       [](char c) { return std::isxdigit(static_cast<unsigned char>(c)) != 0; });
}

std::string upper(std::string_view text) {
    std::string out(text);
    for (auto& c : out)
        c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    return out;
}

void check_reply(const Exchange& exchange, ModuleType type, const OwnedFrame& frame) {
    const auto reading = decode(exchange, frame.bytes);
    if (frame.overflowed) return;  // the link reports these itself; decode() must only not crash
    if (is_output(type)) {
        check(reading.has_value() == (frame.bytes == "1"), "an output acknowledges with 1 only");
        if (reading) check(reading->count == 0, "an acknowledgement carries no words");
        if (!reading)
            check(reading.error().code == (frame.bytes == "0" ? Errc::error_ack : Errc::malformed),
                  "0 is an error ack, anything else malformed");
    } else {
        const bool valid = frame.bytes.size() == reply_length(type) && all_hex(frame.bytes);
        check(reading.has_value() == valid, "a reading is exactly reply_length hex digits");
        if (reading) {
            check(reading->count == reply_words(type), "a reading has the type's word count");
            check(encode_reading(type, reading->raw) == upper(frame.bytes) + cr,
                  "a reading encodes back to its frame");
        } else {
            check(reading.error().code == Errc::malformed, "a bad reading is malformed");
        }
    }
    if (!reading) check(!reading.error().message.empty(), "every error says what was wrong");
}

// What a module accepts: its letter, its number, and the payload its type takes. The simulator
// also takes the letter O for an rgbdm's off (protocol.md §3), and hex digits in either case.
void check_request(const OwnedFrame& frame) {
    const auto request = parse_request(frame.bytes);
    if (frame.overflowed) return;
    if (!request) {
        check(request.error().code == Errc::malformed, "a bad request is malformed");
        return;
    }
    std::string canonical = frame.bytes;
    const auto type = request->module.type;
    if (type == ModuleType::dom16) canonical = canonical.substr(0, 2) + upper(canonical.substr(2));
    if (type == ModuleType::rgbdm && canonical.size() == 3 && canonical[2] == 'O')
        canonical[2] = '0';
    const auto encoded = encode_request(request->module, request->output_value);
    check(encoded.has_value(), "a parsed request can be sent");
    if (encoded) check(*encoded == canonical + cr, "a request encodes back to its frame");
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace ioport;
    if (size < 2) return 0;
    const auto type = static_cast<ModuleType>(data[0] % all_module_types.size());
    const ModuleAddress module{type, static_cast<std::uint8_t>(data[0] / 9 % modules_per_type)};
    const std::size_t chunk = 1 + data[1] % 64;
    const std::string_view stream(reinterpret_cast<const char*>(data + 2), size - 2);

    // Every module can be addressed; 0 is a valid value for every output type.
    const auto exchange = make_exchange(module, 0);
    fuzz::check(exchange.has_value(), "every module has an exchange");
    fuzz::check(exchange->terminator == cr && exchange->reply_length == reply_length(type),
                "an ioport reply is reply_length characters and a CR");
    for (const auto& frame : fuzz::line_frames(cr, exchange->reply_length, stream, chunk))
        fuzz::check_reply(*exchange, type, frame);
    for (const auto& frame : fuzz::line_frames(cr, max_request_length, stream, chunk))
        fuzz::check_request(frame);
    return 0;
}
