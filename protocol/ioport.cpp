#include "protocol/ioport.hpp"

#include <algorithm>
#include <charconv>

#include <fmt/format.h>

#include "protocol/hex.hpp"

namespace ioport {
namespace {

// Indexed by the enums. A table with fewer entries than its enum has values would still compile,
// the rest empty: the static_asserts catch that.
constexpr std::array<std::string_view, module_type_count> type_names{
    "dim16", "dom16", "acm3p", "acm3c", "lim16", "rgbdm", "dccim", "dcvim", "mux8m"};
static_assert(std::ranges::none_of(type_names, &std::string_view::empty), "a type has no name");
constexpr std::array<std::string_view, colour_count> colour_names{
    "off", "red", "green", "blue", "cyan", "magenta", "yellow", "white"};
static_assert(std::ranges::none_of(colour_names, &std::string_view::empty), "a colour has no name");
constexpr std::array<char, colour_count> colour_codes{'0', 'R', 'G', 'B', 'C', 'M', 'Y', 'W'};
static_assert(std::ranges::count(colour_codes, '\0') == 0, "a colour has no wire code");

bool is_module_digit(char c) {
    return c >= '0' && c < '0' + modules_per_type;
}

}  // namespace

std::string_view name(ModuleType type) {
    return type_names[static_cast<std::size_t>(type)];
}

std::optional<ModuleType> module_type_from_name(std::string_view text) {
    for (const auto type : all_module_types)
        if (name(type) == text) return type;
    return std::nullopt;
}

std::optional<ModuleType> module_type_from_letter(char c) {
    if (c < 'a' || c >= 'a' + module_type_count) return std::nullopt;
    return static_cast<ModuleType>(c - 'a');
}

int reply_words(ModuleType type) {
    switch (type) {
        case ModuleType::acm3p:
        case ModuleType::acm3c:
            return 3;
        case ModuleType::dom16:
        case ModuleType::rgbdm:
        case ModuleType::mux8m:
            return 0;
        case ModuleType::dim16:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;
    }
    return 1;
}

std::size_t reply_length(ModuleType type) {
    return is_output(type) ? 1 : static_cast<std::size_t>(reply_words(type)) * 4;
}

std::string to_string(ModuleAddress module) {
    return fmt::format("{} {}", name(module.type), module.number);
}

Result<ModuleAddress> parse_module_address(std::string_view text) {
    const auto sep = text.find_first_of(":/ ");
    const auto bad = [&] {
        return fail(Errc::invalid_argument,
                    fmt::format("'{}' is not a module: write TYPE:NUMBER, e.g. dim16:0, with TYPE "
                                "one of {} and NUMBER 0-7",
                                text, fmt::join(type_names, " ")));
    };
    if (sep == std::string_view::npos) return bad();
    const auto type = module_type_from_name(text.substr(0, sep));
    const auto number = text.substr(sep + 1);
    if (!type || number.size() != 1 || !is_module_digit(number[0])) return bad();
    return ModuleAddress{*type, static_cast<std::uint8_t>(number[0] - '0')};
}

std::string_view name(Colour colour) {
    return colour_names[static_cast<std::size_t>(colour)];
}
char wire_code(Colour colour) {
    return colour_codes[static_cast<std::size_t>(colour)];
}

std::optional<Colour> colour_from_name(std::string_view text) {
    for (std::size_t i = 0; i < colour_names.size(); ++i)
        if (colour_names[i] == text) return static_cast<Colour>(i);
    return std::nullopt;
}

std::optional<Colour> colour_from_wire_code(char code) {
    for (std::size_t i = 0; i < colour_codes.size(); ++i)
        if (colour_codes[i] == code) return static_cast<Colour>(i);
    return std::nullopt;
}

std::optional<MuxSetting> mux_from_value(std::uint16_t value) {
    const MuxSetting mux{static_cast<std::uint8_t>(value >> 8),
                         static_cast<std::uint8_t>(value & 0xFF)};
    if (mux.pos >= mux_test_points || mux.neg >= mux_test_points) return std::nullopt;
    return mux;
}

Result<> validate_output_value(ModuleType type, std::uint16_t value) {
    switch (type) {
        case ModuleType::dom16:
            return {};
        case ModuleType::rgbdm:
            if (value < colour_count) return {};
            return fail(Errc::invalid_argument,
                        fmt::format("rgbdm colour {} is out of range: use 0-7 (off red green blue "
                                    "cyan magenta yellow white)",
                                    value));
        case ModuleType::mux8m:
            if (mux_from_value(value)) return {};
            return fail(Errc::invalid_argument,
                        fmt::format("mux8m value 0x{:04X} is out of range: (pos << 8) | neg with "
                                    "pos and neg 0-7",
                                    value));
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;
    }
    return fail(Errc::invalid_argument,
                fmt::format("{} is an input module: it takes no output value", name(type)));
}

Result<std::string> encode_request(ModuleAddress module, std::uint16_t output_value) {
    if (module.number >= modules_per_type)
        return fail(Errc::invalid_argument,
                    fmt::format("module number {} is out of range 0-7", module.number));
    std::string frame{letter(module.type), static_cast<char>('0' + module.number)};
    if (is_output(module.type)) {
        if (auto ok = validate_output_value(module.type, output_value); !ok)
            return Unexpected(ok.error());
    }
    switch (module.type) {
        case ModuleType::dom16:
            append_hex4(frame, output_value);
            break;
        case ModuleType::rgbdm:
            frame += wire_code(static_cast<Colour>(output_value));
            break;
        case ModuleType::mux8m: {
            const auto mux = *mux_from_value(output_value);
            frame += static_cast<char>('0' + mux.pos);
            frame += static_cast<char>('0' + mux.neg);
            break;
        }
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;  // a read: the address alone
    }
    frame += cr;
    return frame;
}

Result<Reading> parse_reply(ModuleType type, std::string_view frame) {
    if (is_output(type)) {
        if (frame == "1") return Reading{};
        if (frame == "0")
            return fail(Errc::error_ack, fmt::format("{} answered 0 (error)", name(type)));
        return fail(Errc::malformed, fmt::format("{} answered \"{}\", expected 1 or 0", name(type),
                                                 printable(frame)));
    }
    const std::size_t expected = reply_length(type);
    if (frame.size() != expected)
        return fail(Errc::malformed,
                    fmt::format("{} answered \"{}\" ({} characters), expected {} hex digits",
                                name(type), printable(frame), frame.size(), expected));
    Reading reading;
    reading.count = reply_words(type);
    for (int i = 0; i < reading.count; ++i) {
        const auto word = parse_hex4(frame.substr(static_cast<std::size_t>(i) * 4, 4));
        if (!word)
            return fail(Errc::malformed, fmt::format("{} answered \"{}\": not hex digits",
                                                     name(type), printable(frame)));
        reading.raw[static_cast<std::size_t>(i)] = *word;
    }
    return reading;
}

Unit engineering_unit(ModuleType type) {
    switch (type) {
        case ModuleType::acm3p:
        case ModuleType::acm3c:
            return Unit::percent;
        case ModuleType::dccim:
            return Unit::ampere;
        case ModuleType::dcvim:
            return Unit::volt;
        case ModuleType::dim16:
        case ModuleType::dom16:
        case ModuleType::lim16:
        case ModuleType::rgbdm:
        case ModuleType::mux8m:
            break;
    }
    return Unit::none;
}

std::string_view symbol(Unit unit) {
    switch (unit) {
        case Unit::percent:
            return "%";
        case Unit::ampere:
            return "A";
        case Unit::volt:
            return "V";
        case Unit::none:
            return "";
    }
    return "";
}

double full_scale(ModuleType type) {
    switch (engineering_unit(type)) {
        case Unit::percent:
            return 100.0;
        case Unit::ampere:
            return 6.0;
        case Unit::volt:
            return 32.0;
        case Unit::none:
            return 0.0;
    }
    return 0.0;
}

double engineering_value(ModuleType type, std::uint16_t raw) {
    if (engineering_unit(type) == Unit::none) return raw;
    return raw / 65535.0 * full_scale(type);
}

Result<DeviceRequest> parse_request(std::string_view frame) {
    const auto bad = [&](std::string_view why) {
        return fail(Errc::malformed, fmt::format("request \"{}\": {}", printable(frame), why));
    };
    if (frame.size() < 2) return bad("too short");
    const auto type = module_type_from_letter(frame[0]);
    if (!type) return bad("unknown module letter");
    if (!is_module_digit(frame[1])) return bad("module number is not 0-7");
    DeviceRequest request{{*type, static_cast<std::uint8_t>(frame[1] - '0')}, 0};
    const auto payload = frame.substr(2);
    switch (*type) {
        case ModuleType::dom16: {
            const auto word = payload.size() == 4 ? parse_hex4(payload) : std::nullopt;
            if (!word) return bad("dom16 needs 4 hex digits");
            request.output_value = *word;
            break;
        }
        case ModuleType::rgbdm: {
            // The seed's own example sends 'O' (letter) for off; a real bar accepts it, so do we.
            const auto colour = payload.size() != 1
                                    ? std::nullopt
                                    : colour_from_wire_code(payload[0] == 'O' ? '0' : payload[0]);
            if (!colour) return bad("rgbdm needs one of R G B C M Y W 0");
            request.output_value = static_cast<std::uint16_t>(*colour);
            break;
        }
        case ModuleType::mux8m:
            if (payload.size() != 2 || !is_module_digit(payload[0]) || !is_module_digit(payload[1]))
                return bad("mux8m needs two test points 0-7");
            request.output_value = MuxSetting{static_cast<std::uint8_t>(payload[0] - '0'),
                                              static_cast<std::uint8_t>(payload[1] - '0')}
                                       .value();
            break;
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            if (!payload.empty()) return bad("a read request has no payload");
            break;
    }
    return request;
}

std::string encode_reading(ModuleType type, std::span<const std::uint16_t> raw) {
    std::string frame;
    const auto words =
        std::min<std::size_t>(raw.size(), static_cast<std::size_t>(reply_words(type)));
    for (std::size_t i = 0; i < words; ++i)
        append_hex4(frame, raw[i]);
    frame += cr;
    return frame;
}

std::string encode_ack(bool ok) {
    return ok ? std::string{"1\r"} : std::string{"0\r"};
}

}  // namespace ioport
