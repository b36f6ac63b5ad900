// Fuzz target: replies from an ID-2, as the gateway receives them, and request bytes to one, as
// the simulator does.
//
// Input: byte 0 chooses the command (I, C, R: byte % 3), byte 1 the size of the serial reads
// (1 + byte % 64), the rest is what arrives on the line. Every frame is decoded as the reply to
// the command (decode(), as SerialLink::transact does) and checked against protocol.md §2,
// worked out here independently; every byte is parsed as a request, as the simulator does.
#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "fuzz/fuzz.hpp"
#include "fuzz/line_frames.hpp"
#include "protocol/exchange.hpp"
#include "protocol/id2.hpp"

namespace ioport::fuzz {
namespace {

constexpr std::array commands{id2::Command::stop_input, id2::Command::count, id2::Command::reset};

// The reply's value, or nullopt when the frame is not a reply to `command`.
std::optional<std::uint16_t> expected_value(id2::Command command, std::string_view frame) {
    switch (command) {
        case id2::Command::stop_input:
            if (frame == "0" || frame == "1") return static_cast<std::uint16_t>(frame[0] - '0');
            return std::nullopt;
        case id2::Command::count: {
            if (frame.size() != 5 || !std::all_of(frame.begin(), frame.end(),
                                                  [](char c) { return c >= '0' && c <= '9'; }))
                return std::nullopt;
            const int value = std::stoi(std::string(frame));
            if (value > 65535) return std::nullopt;
            return static_cast<std::uint16_t>(value);
        }
        case id2::Command::reset:
            if (frame == "OK") return std::uint16_t{0};
            return std::nullopt;
    }
    return std::nullopt;
}

std::string encoded(id2::Command command, std::uint16_t value) {
    switch (command) {
        case id2::Command::stop_input:
            return id2::encode_stop_input(value != 0);
        case id2::Command::count:
            return id2::encode_count(value);
        case id2::Command::reset:
            break;
    }
    return id2::encode_reset_ok();
}

void check_reply(const Exchange& exchange, id2::Command command, const OwnedFrame& frame) {
    const auto reading = decode(exchange, frame.bytes);
    if (frame.overflowed) return;  // the link reports these itself; decode() must only not crash
    const auto value = expected_value(command, frame.bytes);
    check(reading.has_value() == value.has_value(), "a reply is decoded when it is well formed");
    if (!reading) {
        check(reading.error().code == Errc::malformed && !reading.error().message.empty(),
              "a bad reply is malformed, and the message says how");
        return;
    }
    const bool has_word = command != id2::Command::reset;
    check(reading->count == (has_word ? 1 : 0), "I and C carry one word, R none");
    if (has_word) check(reading->raw[0] == *value, "the decoded value is the reply's");
    check(encoded(command, *value) == frame.bytes + id2::lf, "a reply encodes back to its frame");
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace ioport;
    if (size < 2) return 0;
    const auto command = fuzz::commands[data[0] % fuzz::commands.size()];
    const std::size_t chunk = 1 + data[1] % 64;
    const std::string_view stream(reinterpret_cast<const char*>(data + 2), size - 2);

    const auto exchange = make_exchange(command);
    fuzz::check(exchange.terminator == id2::lf &&
                    exchange.reply_length == id2::reply_length(command) &&
                    exchange.request == std::string(1, static_cast<char>(command)),
                "an ID-2 request is one character, its reply reply_length characters and a LF");
    for (const auto& frame : fuzz::line_frames(id2::lf, exchange.reply_length, stream, chunk))
        fuzz::check_reply(exchange, command, frame);
    // The device takes requests byte by byte, without a terminator.
    for (const char byte : stream) {
        const auto request = id2::parse_request(byte);
        const bool known = byte == 'I' || byte == 'C' || byte == 'R';
        fuzz::check(request.has_value() == known, "I, C and R are the only requests");
        if (request)
            fuzz::check(id2::encode_request(*request) == std::string(1, byte),
                        "a request encodes back to its byte");
    }
    return 0;
}
