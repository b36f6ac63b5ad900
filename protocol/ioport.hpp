// The ioport hub protocol (hub8u / hub8r): one ASCII request, one CR-terminated reply.
// Pure functions over bytes and values; see ../shared/spec/protocol.md §1.
#pragma once

#include <array>
#include <compare>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "protocol/error.hpp"

namespace ioport {

inline constexpr char cr = '\r';
inline constexpr int modules_per_type = 8;
inline constexpr int slot_count = 72;  // 9 types × 8 module numbers
// Longest request frame before the CR: dom16, "b0HHHH".
inline constexpr std::size_t max_request_length = 6;

// Declaration order is the protocol's letter order: dim16 = 'a' … mux8m = 'i'. A new type goes
// last and module_type_count below counts it; then every switch over ModuleType (none has a
// default), every table of names and the slot count fail to compile until they handle it.
enum class ModuleType : std::uint8_t {
    dim16,
    dom16,
    acm3p,
    acm3c,
    lim16,
    rgbdm,
    dccim,
    dcvim,
    mux8m
};

inline constexpr int module_type_count = static_cast<int>(ModuleType::mux8m) + 1;
static_assert(slot_count == module_type_count * modules_per_type, "a slot for every module");

inline constexpr std::array all_module_types{
    ModuleType::dim16, ModuleType::dom16, ModuleType::acm3p, ModuleType::acm3c, ModuleType::lim16,
    ModuleType::rgbdm, ModuleType::dccim, ModuleType::dcvim, ModuleType::mux8m};
static_assert(
    std::ssize(all_module_types) == module_type_count &&
        [] {
            for (int i = 0; i < module_type_count; ++i)
                if (static_cast<int>(all_module_types[i]) != i) return false;
            return true;
        }(),
    "every module type, in declaration order");

constexpr char letter(ModuleType type) {
    return static_cast<char>('a' + static_cast<int>(type));
}
std::string_view name(ModuleType type);
std::optional<ModuleType> module_type_from_name(std::string_view name);
std::optional<ModuleType> module_type_from_letter(char letter);

// dom16, rgbdm and mux8m take a command and answer with an acknowledgement; the rest are read.
constexpr bool is_output(ModuleType type) {
    return type == ModuleType::dom16 || type == ModuleType::rgbdm || type == ModuleType::mux8m;
}
// 16-bit words in a read reply: 3 for the three-channel analog modules, else 1 (0 for outputs).
int reply_words(ModuleType type);
// Characters of the reply frame before the CR.
std::size_t reply_length(ModuleType type);

struct ModuleAddress {
    ModuleType type;
    std::uint8_t number;  // 0..7, the module's address switch
    friend constexpr auto operator<=>(const ModuleAddress&, const ModuleAddress&) = default;
};

// Slot = type index × 8 + number: dim16 0 → 0, dom16 3 → 11, mux8m 7 → 71.
constexpr int slot(ModuleAddress module) {
    return static_cast<int>(module.type) * modules_per_type + module.number;
}
constexpr ModuleAddress module_at_slot(int slot) {
    return {static_cast<ModuleType>(slot / modules_per_type),
            static_cast<std::uint8_t>(slot % modules_per_type)};
}
std::string to_string(ModuleAddress module);  // "dim16 0"
// Parses "dim16:0", "dim16/0" or "dim16 0".
Result<ModuleAddress> parse_module_address(std::string_view text);

// --- Output values --------------------------------------------------------------------------
// Every output module's state is one 16-bit value, the same as its Modbus holding register:
// dom16 the output word (bit k = output k), rgbdm a colour code, mux8m (pos << 8) | neg.

enum class Colour : std::uint8_t { off, red, green, blue, cyan, magenta, yellow, white };
inline constexpr int colour_count = static_cast<int>(Colour::white) + 1;
std::string_view name(Colour colour);
char wire_code(Colour colour);  // '0' R G B C M Y W
std::optional<Colour> colour_from_name(std::string_view name);
std::optional<Colour> colour_from_wire_code(char code);

struct MuxSetting {
    std::uint8_t pos;  // test point switched onto dev+
    std::uint8_t neg;  // test point switched onto dev-
    constexpr std::uint16_t value() const { return static_cast<std::uint16_t>(pos << 8 | neg); }
    constexpr bool disconnected() const { return pos == neg; }
};
inline constexpr int mux_test_points = 8;
std::optional<MuxSetting> mux_from_value(std::uint16_t value);  // nullopt if a byte is over 7

// Whether `value` can be commanded to an output module of this type.
Result<> validate_output_value(ModuleType type, std::uint16_t value);

// --- Master side (the gateway, ioportctl) ----------------------------------------------------

// The request frame, CR included. For input modules `output_value` is ignored.
Result<std::string> encode_request(ModuleAddress module, std::uint16_t output_value = 0);

struct Reading {
    std::array<std::uint16_t, 3> raw{};
    int count = 0;  // words in raw: 1 or 3 for input modules, 0 for an output acknowledgement
    friend bool operator==(const Reading&, const Reading&) = default;
};

// Parses a reply frame (CR stripped) from a module of this type. A read reply must be exactly
// reply_length() hex digits (either case); an output reply must be "1" (ok) or "0" (error_ack).
Result<Reading> parse_reply(ModuleType type, std::string_view frame);

// --- Engineering units, as the vendor library computes them ---------------------------------

enum class Unit { none, percent, ampere, volt };
Unit engineering_unit(ModuleType type);
std::string_view symbol(Unit unit);  // "%", "A", "V", ""
double full_scale(ModuleType type);  // 100, 6, 32; 0 for modules without engineering value
// raw / 65535 * full scale.
double engineering_value(ModuleType type, std::uint16_t raw);

// --- Device side (the simulator) -------------------------------------------------------------

struct DeviceRequest {
    ModuleAddress module;
    std::uint16_t output_value = 0;  // as above; 0 for reads
    friend bool operator==(const DeviceRequest&, const DeviceRequest&) = default;
};
// Parses a request frame (CR stripped) as a module would: anything not exactly right is an error.
Result<DeviceRequest> parse_request(std::string_view frame);
// A read reply with the CR: 4 or 12 upper-case hex digits.
std::string encode_reading(ModuleType type, std::span<const std::uint16_t> raw);
std::string encode_ack(bool ok);

}  // namespace ioport
