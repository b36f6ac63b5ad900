// The gateway's Modbus map (../shared/spec/gateway.md §2–§4) as pure functions: where each
// module's data lives in the four tables of its unit, which request is allowed and what it
// asks of the devices, how readings and diagnostics are written into the tables, and the
// printable map. No I/O: the daemon owns the tables and the clock and calls in here.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "protocol/id2.hpp"
#include "protocol/ioport.hpp"
#include "protocol/modbus.hpp"
#include "protocol/tags.hpp"

namespace ioport::gateway {

enum class UnitKind : std::uint8_t { ioport, id2 };
enum class WordOrder : std::uint8_t { big, little };  // 32-bit values: high word first or last
enum class Stale : std::uint8_t { exception, hold };  // reads of modules that are not online

// Table sizes of every unit: the highest address of any block + 1.
inline constexpr std::size_t coil_count = 128;
inline constexpr std::size_t discrete_input_count = 1072;
inline constexpr std::size_t holding_register_count = 24;
inline constexpr std::size_t input_register_count = 1272;

// Value of input register 1100 + slot.
enum class ModuleStatus : std::uint16_t {
    not_configured = 0,
    online = 1,
    no_answer = 2,
    bad_answer = 3,  // a malformed answer or an error ack
    not_polled = 4,
};

// Value of input register 1000.
enum class LinkState : std::uint16_t { port_not_open = 0, all_online = 1, some_offline = 2 };

// A unit's four tables. The daemon keeps them in a libmodbus mapping; tests in vectors.
struct Tables {
    std::span<std::uint8_t> coils;               // coil_count, one byte per bit (0/1)
    std::span<std::uint8_t> discrete_inputs;     // discrete_input_count
    std::span<std::uint16_t> holding_registers;  // holding_register_count
    std::span<std::uint16_t> input_registers;    // input_register_count
};

// --- 32-bit values --------------------------------------------------------------------------

std::array<std::uint16_t, 2> words(std::uint32_t value, WordOrder order);
std::array<std::uint16_t, 2> words(float value, WordOrder order);  // IEEE 754 bits
// The vendor formula raw / 65535 × full scale, rounded once to single precision.
float engineering_float(ModuleType type, std::uint16_t raw);

// --- Requests -------------------------------------------------------------------------------

// What the planner needs to know of a unit at the moment a request arrives.
// The value of a module's point (protocol/points.hpp): boolean as bool, the integers as their
// number, float32 as float.
using PointValue = std::variant<bool, std::uint64_t, float>;

struct UnitState {
    UnitKind kind = UnitKind::ioport;
    bool port_open = false;
    std::array<ModuleStatus, slot_count> status{};  // not_configured where no module is
};

struct Policy {
    bool read_only = false;
    Stale stale = Stale::exception;
};

// One output module's new state: new = (desired & ~mask) | (value & mask), applied to the
// desired state when the command is sent, so that two clients writing different coils of one
// dom16 do not undo each other.
struct OutputChange {
    ModuleAddress module;
    std::uint16_t mask = 0xFFFF;
    std::uint16_t value = 0;
    friend bool operator==(const OutputChange&, const OutputChange&) = default;
};
// The value to command: the bits of `change.mask` from `change.value`, the rest as `desired`.
std::uint16_t merged(std::uint16_t desired, const OutputChange& change);

// Answer from the tables as they are. `diagnostics`: the request touches the diagnostics
// blocks, whose time-dependent values must be brought up to date first.
struct ReadPlan {
    bool diagnostics = false;
    friend bool operator==(const ReadPlan&, const ReadPlan&) = default;
};
// Send these commands, in order, and answer after the device acknowledged them all.
// Empty changes and no reset: nothing to send (ID-2 coil 0 written with 0).
struct WritePlan {
    std::vector<OutputChange> changes;
    bool reset_counter = false;  // ID-2 coil 0 written with 1
    // FC 23: these holding registers are read once the write is done (read_back()).
    std::uint16_t read_address = 0;
    std::uint16_t read_quantity = 0;
    friend bool operator==(const WritePlan&, const WritePlan&) = default;
};
using Plan = std::variant<modbus::Exception, ReadPlan, WritePlan>;

// Decides a request PDU for a unit that exists (unknown units answer 0A before this), with the
// precedence of gateway.md §4: unsupported function 01 → read_only and a write 01 → limits 03 →
// outside a block or running past its end 02 → unconfigured module on a write 02 → bad value
// (colour or mux byte over 7) 03 → port closed on a write, or a data address of a configured
// module that is not online on a read with Stale::exception 0B.
// FC 23 (§5.2) is planned as its write, and both its ranges must lie in a block (02).
Plan plan(const UnitState& unit, const Policy& policy, std::span<const std::uint8_t> pdu);
// FC 23's read part, decided once its write succeeded, as FC 03 of the same range would be then:
// 0B for a module that is not online with Stale::exception, else a ReadPlan.
Plan read_back(const UnitState& unit, const Policy& policy, std::uint16_t address,
               std::uint16_t quantity);

// --- The tables -----------------------------------------------------------------------------

// Raw words and float32 values of an ioport input module (dim16, lim16, acm3p, acm3c, dccim,
// dcvim) from a good reading. The float32 registers carry each channel's engineering value
// (§6.1): its value<ch> among the module's point `values` (protocol/points.hpp), made from this
// reading, as every output shows it.
void store_reading(const Tables& tables, ModuleAddress module, const Reading& reading,
                   WordOrder order, std::span<const std::optional<PointValue>> values);
// A confirmed output state: dom16 holding register n and coils 16n…16n+15; rgbdm 8 + n;
// mux8m 16 + n.
void store_output(const Tables& tables, ModuleAddress module, std::uint16_t value);
// ID-2: the stop input (discrete input 0) or the counter (input register 0).
void store_id2(const Tables& tables, id2::Command command, std::uint16_t value);

struct Diagnostics {
    LinkState link_state = LinkState::port_not_open;
    std::chrono::microseconds last_cycle{};  // between the last two cycle completions
    std::uint64_t cycles = 0;
    std::uint64_t transactions_ok = 0;
    std::uint64_t transactions_failed = 0;
    std::uint64_t opens = 0;
    std::array<ModuleStatus, slot_count> status{};
    // ms since each module's last good transaction; values over 65535 (and "never") saturate.
    std::array<std::uint32_t, slot_count> age_ms{};
};
// Input registers 1000–1009, 1100–1171, 1200–1271 and discrete inputs 1000–1071. Counters are
// reported modulo 2^32; 1001 in 0.1 ms saturating at 65535; 1200 + slot reads 65535 for
// unconfigured slots.
void store_diagnostics(const Tables& tables, const Diagnostics& diagnostics, WordOrder order);

// §5.1: what the Modbus server counts for a unit, as it sends each response.
struct Traffic {
    std::uint64_t requests = 0;  // exceptions included
    std::uint64_t exceptions = 0;
    std::uint64_t writes_confirmed = 0;  // client writes answered normally
    std::uint64_t writes_failed = 0;     // client writes answered 04 or 0B
};
// Counts one response (PDU, function code first) to a request of `function`: writes are FC 05,
// 06, 15, 16 and 23.
void count_response(Traffic& traffic, std::uint8_t function,
                    std::span<const std::uint8_t> response);

// Input registers 1010-1020 of a unit: its traffic, and the server's own state.
struct Front {
    Traffic traffic;
    std::size_t connections = 0;                         // open now, every listener
    std::chrono::microseconds since_previous_request{};  // before the request being answered
    bool comm_loss = false;  // §5.3: outputs were put in their safe state
};
// Counters modulo 2^32 in `order`; 1018 and 1019 (in whole seconds) saturate at 65535.
void store_front(const Tables& tables, const Front& front, WordOrder order);

// --- The printable map (ioportd --print-map) ------------------------------------------------

struct MapRow {
    modbus::Table table;
    std::uint16_t address;  // PDU address, 0-based
    int unit_id;
    std::string module;       // "dim16 0", "ID-2", "link hub0"
    std::string channel;      // "i3", "c1", "" when the row is the whole module
    std::string data_type;    // bit, uint16, uint32, float32
    std::string units;        // %, A, V, ms, 0.1 ms, or ""
    std::string access;       // read, read/write, write
    std::string description;  // "input 3", "colour: 0 off … 7 white", …
    // gateway.md §6.1, after the ten columns of §4 so that readers of those keep working:
    std::string module_name;   // "boiler 1"; the module's id when not configured; "" for the link
    std::string channel_name;  // the channel's or point's configured name, else ""
};
// "000001", "100001", "300001", "400001" + address.
std::string modicon_number(modbus::Table table, std::uint16_t address);

struct UnitMap {
    UnitKind kind;
    int unit_id;
    std::string link_name;
    std::vector<ModuleAddress> modules;  // ioport only
    std::vector<ModuleTags> tags{};      // parallel to `modules`; none: every default
};
// Every address of the unit's configured modules and its diagnostics (32-bit values one row at
// their first address), ordered by table (coils, discrete inputs, holding registers, input
// registers) then address.
std::vector<MapRow> map_rows(const UnitMap& unit);
std::string format_markdown(std::span<const MapRow> rows);
std::string format_csv(std::span<const MapRow> rows);  // RFC 4180, header line first

}  // namespace ioport::gateway
