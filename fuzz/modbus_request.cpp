// Fuzz target: the Modbus request path, from the bytes of a client's TCP stream to the responses
// and the changes of the process image, against a configured map.
//
// It runs what ModbusServer::serve, ::answer and ::write run, minus the sockets and the serial
// links: modbus::next_adu frames the stream, the unit is looked up as set_units() arranges them,
// Read Device Identification (FC 43) is answered from the unit's identity right after the lookup,
// gateway::plan() decides everything else, a write's changes are merged and stored as
// LinkScheduler::apply does once the device answered, FC 23's read part is decided by
// gateway::read_back() once its write is done, libmodbus builds the response through the
// daemon's own ReplyBuilder, and each response is counted once, into gateway::RequestCounts, which
// keeps /metrics' counts and each unit's traffic (a read of the diagnostics stores it with
// gateway::store_front), as ModbusServer::count does.
//
// Input: a scenario of `scenario_length` bytes, then the stream.
//   byte 0     bit 0 read_only, bit 1 stale: hold, bit 2 only the hub is configured (so unit ids
//              0 and 255 reach it too), bit 3 the hub's port is closed, bit 4 the ID-2's port is
//              closed, bit 5 word_order: little, bit 6 communication loss (§5.3) before the
//              first request
//   bytes 1-8  two bits per configured module, in configuration order (the ID-2 last): its
//              status, 0 online, 1 no answer, 2 bad answer, 3 not polled yet
//   bytes 9-10 two bits per device command sent for a write, cycling: 0 and 1 acknowledged,
//              2 error ack, 3 no answer
// All zeros is the everyday case: every port open, every module online, every command acked.
//
// Invariants, from gateway.md rather than from the code under test:
// - each response echoes the request's transaction id and unit id, has a consistent length and
//   is one of the responses the request allows (the exception planned, with the high bit set, or
//   the normal response whose values are the image's);
// - a planned request lies inside one block of §4 (the diagnostics are 1000-1020); FC 23's write
//   and read ranges both lie in the holding registers 0-23;
// - the image changes only at the outputs of modules whose device acknowledged a write, to the
//   merged value, and a dom16's coils and register always agree;
// - FC 23 (§5.2): a failed write answers its exception and reads nothing; otherwise the response
//   is function 0x17, a byte count of 2 x the read quantity and the holding registers as they
//   are after the write (or 0B, with stale: exception, when the read touches a module that is not
//   online then);
// - FC 43/14 (§5.2, MAP v1.1b3 §6.21): a MEI type other than 14 answers 01, a Read Device ID code
//   outside 01-04 answers 03, code 04 answers exactly the one object asked for or 02; otherwise
//   the PDU is 2B 0E <code> 82 <more follows 00|FF> <next object id> <number of objects> and the
//   objects, whose ids are at most 6, increasing and consecutive from where the stream starts
//   (the object asked for, or 0x00 when it is not one of the category's: 00-02 basic, 00-06
//   regular and extended), each the unit's value; "more follows" exactly when the next object
//   does not fit; the image does not change, whatever the port, the modules or read_only;
// - the traffic counters (§5.1): requests >= exceptions, writes confirmed + failed <= requests,
//   and they count as the spec says (every response to a known unit is a request, a response
//   with the high bit an exception, FC 05/06/15/16/23 answered normally a confirmed write and
//   answered 04 or 0B a failed one); a read of 1010-1020 returns them as they were before that
//   request, in the configured word order, 1018 the one connection, 1019 the seconds since the
//   previous request saturating at 65535, 1020 1 only for the first request after a
//   communication loss and else 0;
// - /metrics (§5.4): a response counts once under its unit's id, `other` when no link has the
//   unit id asked for (0 and 255 count as the hub's when it is the only link), and under its
//   function code when it is one of §3.5's, else `other`; an exception counts under its code,
//   which is always one of the server's (01-04, 0A, 0B), never one the client chose; so there
//   are never more series than (configured units + 1) x 11;
// - an unfinished request always fits the server's buffer.
#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/modbus/device_identity.hpp"
#include "daemon/modbus/modbus_reply.hpp"
#include "fuzz/fuzz.hpp"
#include "protocol/device_identification.hpp"
#include "protocol/gateway_map.hpp"
#include "protocol/modbus.hpp"
#include "protocol/points.hpp"
#include "protocol/request_labels.hpp"

namespace ioport::fuzz {
namespace {

using daemon::Bytes;
using gateway::ModuleStatus;
using modbus::Exception;
using modbus::Table;

constexpr std::size_t scenario_length = 11;

// Two modules of every type, a dom16 pair side by side (one write can span both), and an ID-2.
// The hub's identity has objects of the longest length allowed, so that a stream of the regular
// objects does not fit one response ("more follows"); the ID-2 has ioportd's own.
constexpr std::string_view configuration = R"(
modbus:
  listen: "127.0.0.1:1502"
links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    unit_id: 1
    identity:
      vendor_name: "Vendor name of sixty-four printable characters: a response fills"
      product_code: "Product code of 64 characters, so that a stream fits no one PDU."
      vendor_url: "Vendor URL of sixty-four characters: https://example.invalid/012"
      product_name: "Product name of sixty-four characters: more follows, then the id"
      model_name: hub8u
    modules:
      - { type: dim16, number: 0 }
      - { type: dim16, number: 7 }
      - { type: dom16, number: 0, initial: 0x00FF }
      - { type: dom16, number: 1 }
      - { type: acm3p, number: 0 }
      - { type: acm3p, number: 3 }
      - { type: acm3c, number: 0 }
      - { type: acm3c, number: 7 }
      - { type: lim16, number: 0 }
      - { type: lim16, number: 5 }
      - { type: rgbdm, number: 0, initial: red }
      - { type: rgbdm, number: 2 }
      - { type: dccim, number: 0 }
      - { type: dccim, number: 6 }
      - { type: dcvim, number: 1 }
      - { type: dcvim, number: 7 }
      - { type: mux8m, number: 0, initial: 0x0707 }
      - { type: mux8m, number: 4 }
  - name: press
    protocol: id2
    device: /dev/ttyUSB1
    unit_id: 2
)";

const config::GatewayConfig& gateway_config() {
    static const auto config = [] {
        auto loaded = config::parse_config(configuration, "fuzz",
                                           [](const std::string& device) { return device; });
        check(loaded.has_value(), "the harness's configuration is valid");
        return *std::move(loaded);
    }();
    return config;
}

// The version the daemon is built as (daemon/CMakeLists.txt); the fuzz target gets the same.
constexpr std::string_view version = IOPORTD_VERSION;

// A link's Read Device Identification objects as gateway.md §5.2 sets them: `identity:` where
// given, else ioportd's own; MajorMinorRevision the version; ModelName "ioport hub" or "ID-2";
// UserApplicationName the link's name.
modbus::DeviceIdentity spec_identity(const config::LinkConfig& link) {
    const bool id2 = link.protocol == config::Protocol::id2;
    constexpr auto revision = static_cast<std::size_t>(modbus::DeviceObject::major_minor_revision);
    const std::array<std::string_view, modbus::device_object_count> defaults{
        "ioportd developers",
        "ioportd",
        version,
        "man:ioportd(8)",
        "ioportd serial-to-Modbus gateway",
        id2 ? "ID-2" : "ioport hub",
        link.name};
    modbus::DeviceIdentity identity;
    for (std::size_t id = 0; id < identity.size(); ++id)
        identity[id] = link.identity[id].empty() || id == revision ? std::string(defaults[id])
                                                                   : link.identity[id];
    return identity;
}

// What the daemon answers (daemon/modbus/device_identity.hpp), checked against the spec's objects.
modbus::DeviceIdentity unit_identity(const config::LinkConfig& link) {
    auto identity = daemon::device_identity(link, version);
    check(identity == spec_identity(link),
          "a unit's identity objects are those of gateway.md §5.2");
    return identity;
}

std::uint16_t be16(std::span<const std::uint8_t> bytes, std::size_t at) {
    return static_cast<std::uint16_t>(bytes[at] << 8 | bytes[at + 1]);
}

// --- The map, as gateway.md §2 and §4 write it ----------------------------------------------

struct Block {
    Table table;
    int first;
    int last;
};

constexpr std::array<Block, 4> diagnostics_blocks{{{Table::input_registers, 1000, 1020},
                                                   {Table::input_registers, 1100, 1171},
                                                   {Table::input_registers, 1200, 1271},
                                                   {Table::discrete_inputs, 1000, 1071}}};
constexpr std::array<Block, 5> ioport_blocks{{{Table::input_registers, 0, 79},
                                              {Table::input_registers, 200, 327},
                                              {Table::discrete_inputs, 0, 255},
                                              {Table::coils, 0, 127},
                                              {Table::holding_registers, 0, 23}}};
constexpr std::array<Block, 3> id2_blocks{
    {{Table::discrete_inputs, 0, 0}, {Table::input_registers, 0, 0}, {Table::coils, 0, 0}}};

bool inside_one_block(gateway::UnitKind kind, Table table, int first, int count) {
    const auto inside = [&](const Block& block) {
        return block.table == table && first >= block.first && first + count - 1 <= block.last;
    };
    const bool data = kind == gateway::UnitKind::ioport
                          ? std::any_of(ioport_blocks.begin(), ioport_blocks.end(), inside)
                          : std::any_of(id2_blocks.begin(), id2_blocks.end(), inside);
    return data || std::any_of(diagnostics_blocks.begin(), diagnostics_blocks.end(), inside);
}

bool in_diagnostics(Table table, int address) {
    return std::any_of(diagnostics_blocks.begin(), diagnostics_blocks.end(), [&](const Block& b) {
        return b.table == table && address >= b.first && address <= b.last;
    });
}

// --- A unit: its state, image and devices -----------------------------------------------------

struct Unit {
    const config::LinkConfig* link = nullptr;
    gateway::UnitState state;
    daemon::UnitImage image;
    std::array<std::uint16_t, slot_count> desired{};  // outputs: last confirmed value
    modbus::DeviceIdentity identity;
    gateway::Traffic counted;  // as gateway.md §5.1 counts: the harness's own
};

// §5.4's label values as the spec words them: a configured unit's id, §3.5's function codes.
int unit_label_as_spec(const Unit* unit) {
    return unit == nullptr ? gateway::other_label : unit->link->unit_id;
}
int function_label_as_spec(std::uint8_t function) {
    constexpr std::array<std::uint8_t, 10> own{1, 2, 3, 4, 5, 6, 15, 16, 23, 43};
    return std::find(own.begin(), own.end(), function) != own.end() ? function
                                                                    : gateway::other_label;
}

std::uint64_t count_of(const gateway::RequestCounts::Counts& counts, std::pair<int, int> key) {
    const auto found = counts.find(key);
    return found == counts.end() ? 0 : found->second;
}

// A copy of a unit's tables. Copied and compared with memcpy and ==, which the coverage
// instrumentation leaves alone: element loops here would cost more than the code under test and
// add nothing but the harness's own branches to the coverage.
struct Image {
    std::array<std::uint8_t, gateway::coil_count> coils;
    std::array<std::uint8_t, gateway::discrete_input_count> discrete_inputs;
    std::array<std::uint16_t, gateway::holding_register_count> holding_registers;
    std::array<std::uint16_t, gateway::input_register_count> input_registers;
};

void take_diagnostics(Image& image, const Image& from) {
    for (const auto& block : diagnostics_blocks) {
        const auto first = static_cast<std::size_t>(block.first);
        const auto count = static_cast<std::size_t>(block.last) + 1 - first;
        if (block.table == Table::input_registers)
            std::memcpy(&image.input_registers[first], &from.input_registers[first],
                        count * sizeof(std::uint16_t));
        else
            std::memcpy(&image.discrete_inputs[first], &from.discrete_inputs[first], count);
    }
}

Image snapshot(const gateway::Tables& tables) {
    Image image;
    std::memcpy(image.coils.data(), tables.coils.data(), sizeof image.coils);
    std::memcpy(image.discrete_inputs.data(), tables.discrete_inputs.data(),
                sizeof image.discrete_inputs);
    std::memcpy(image.holding_registers.data(), tables.holding_registers.data(),
                sizeof image.holding_registers);
    std::memcpy(image.input_registers.data(), tables.input_registers.data(),
                sizeof image.input_registers);
    return image;
}

// What a device answers to the commands of writes.
enum class Answer : std::uint8_t { ack, error_ack, no_answer };

class Devices {
  public:
    explicit Devices(std::uint16_t pattern) : pattern_(pattern) {}
    Answer next() {
        const auto bits = pattern_ >> (2 * (sent_++ % 8)) & 3U;
        return bits < 2 ? Answer::ack : bits == 2 ? Answer::error_ack : Answer::no_answer;
    }

  private:
    std::uint16_t pattern_;
    unsigned sent_ = 0;
};

class Harness {
  public:
    explicit Harness(std::span<const std::uint8_t, scenario_length> scenario);

    // The stream as ModbusServer::serve frames it; ends where the server closes or waits.
    void serve(std::span<const std::uint8_t> stream);

  private:
    void handle(std::span<const std::uint8_t> adu);
    // The outcome; `acked` marks the slots whose device acknowledged its command.
    std::optional<Exception> write(Unit& unit, const gateway::WritePlan& plan,
                                   std::array<bool, slot_count>& acked);
    void refresh_diagnostics(Unit& unit);
    void check_image(const Unit& unit, const Image& before, const modbus::Request* request,
                     const std::array<bool, slot_count>& acked);
    // FC 23's response once its write succeeded.
    void check_read_back(const Unit& unit, const modbus::Request& request,
                         std::span<const std::uint8_t> adu, const Bytes& reply,
                         const gateway::Plan& read) const;
    // Registers 1010-1020 in a read from `address` of `quantity` input registers.
    void check_front(const gateway::Traffic& counted, std::uint16_t address, std::uint16_t quantity,
                     const Bytes& reply) const;
    // Counts a response of `unit` (nullptr: none has the unit id) into /metrics' counts.
    void check_metrics(const Unit* unit, std::uint8_t function, const Bytes& reply);

    gateway::Policy policy_;
    gateway::WordOrder word_order_;
    std::vector<std::unique_ptr<Unit>> units_;
    std::array<Unit*, 256> by_id_{};
    Devices devices_;
    daemon::Mapping scratch_ = daemon::scratch_mapping();
    std::unique_ptr<daemon::ReplyBuilder> replies_;
    std::uint64_t handled_ = 0;
    gateway::RequestCounts metrics_;  // as the server keeps them, for /metrics
    // §5.1 and §5.3 as the server keeps them: the time between the request before this one and
    // this one (a made-up clock, so that 1019 saturates after a few requests), and whether the
    // outputs were put in their safe state since the last request.
    std::chrono::microseconds since_previous_{};
    bool comm_loss_ = false;
};

ModuleStatus status_from(unsigned bits) {
    constexpr std::array statuses{ModuleStatus::online, ModuleStatus::no_answer,
                                  ModuleStatus::bad_answer, ModuleStatus::not_polled};
    return statuses[bits & 3U];
}

// Inputs read as if polled once: each module's words tell its slot and channel.
void store_polled(const Unit& unit, gateway::WordOrder order) {
    const auto& tables = unit.image.tables();
    if (unit.state.kind == gateway::UnitKind::id2) {
        gateway::store_id2(tables, id2::Command::stop_input, 1);
        gateway::store_id2(tables, id2::Command::count, 4242);
        return;
    }
    for (const auto& module : unit.link->modules) {
        if (is_output(module.address.type)) {
            gateway::store_output(tables, module.address, module.initial);
            continue;
        }
        Reading reading{{}, reply_words(module.address.type)};
        for (std::size_t c = 0; c < reading.raw.size(); ++c)
            reading.raw[c] = static_cast<std::uint16_t>(
                static_cast<std::size_t>(slot(module.address)) * 0x0301 + c * 0x1111);
        std::vector<std::optional<gateway::PointValue>> values;
        gateway::point_values(module.address.type, {reading, {}, {}, {}}, module.tags, values);
        gateway::store_reading(tables, module.address, reading, order, values);
    }
}

Harness::Harness(std::span<const std::uint8_t, scenario_length> scenario)
    : policy_{(scenario[0] & 1U) != 0,
              (scenario[0] & 2U) != 0 ? gateway::Stale::hold : gateway::Stale::exception},
      word_order_((scenario[0] & 32U) != 0 ? gateway::WordOrder::little : gateway::WordOrder::big),
      devices_(be16(scenario, 9)),
      comm_loss_((scenario[0] & 64U) != 0) {
    const auto& config = gateway_config();
    const bool hub_only = (scenario[0] & 4U) != 0;
    std::size_t module_index = 0;
    const auto next_status = [&] {
        const auto at = module_index++;
        return status_from(scenario[1 + at / 4 % 8] >> (2 * (at % 4)));
    };
    for (const auto& link : config.links) {
        if (hub_only && link.protocol == config::Protocol::id2) continue;
        auto unit = std::make_unique<Unit>();
        unit->link = &link;
        unit->identity = unit_identity(link);
        // As LinkScheduler's constructor sets the state up, then the scenario's statuses.
        const bool id2 = link.protocol == config::Protocol::id2;
        unit->state.kind = id2 ? gateway::UnitKind::id2 : gateway::UnitKind::ioport;
        unit->state.port_open = (scenario[0] & (id2 ? 16U : 8U)) == 0;
        unit->state.status.fill(ModuleStatus::not_configured);
        if (id2) unit->state.status[0] = next_status();
        for (const auto& module : link.modules) {
            unit->state.status[static_cast<std::size_t>(slot(module.address))] = next_status();
            unit->desired[static_cast<std::size_t>(slot(module.address))] = module.initial;
        }
        store_polled(*unit, word_order_);
        refresh_diagnostics(*unit);
        by_id_[static_cast<std::size_t>(link.unit_id)] = unit.get();
        units_.push_back(std::move(unit));
    }
    if (units_.size() == 1) by_id_[0] = by_id_[255] = units_.front().get();

    auto replies = daemon::ReplyBuilder::create();
    check(replies.has_value(), "a reply builder");
    replies_ = std::move(*replies);
}

void Harness::refresh_diagnostics(Unit& unit) {
    // Counters past 2^32 and saturating values, so that both word orders and every clamp show.
    gateway::Diagnostics d;
    d.link_state =
        unit.state.port_open ? gateway::LinkState::some_offline : gateway::LinkState::port_not_open;
    d.last_cycle = std::chrono::microseconds(static_cast<std::int64_t>(handled_) * 1'234'567);
    d.cycles = handled_ * 0x1'0000'0001ULL;
    d.transactions_ok = handled_ << 20;
    d.transactions_failed = handled_;
    d.opens = 1;
    d.status = unit.state.status;
    for (std::size_t s = 0; s < slot_count; ++s)
        d.age_ms[s] = static_cast<std::uint32_t>(handled_ * 40'000 + s);
    gateway::store_diagnostics(unit.image.tables(), d, word_order_);
}

void Harness::serve(std::span<const std::uint8_t> stream) {
    auto buffered = stream;
    for (;;) {
        const auto next = modbus::next_adu(buffered);
        const bool header = buffered.size() >= modbus::mbap_length;
        const auto length = header ? be16(buffered, 4) : 0;
        if (!next) {
            // §3.5: protocol id not 0, length outside 2..254; closes the connection.
            check(header && (be16(buffered, 2) != 0 || length < 2 || length > 254),
                  "only a malformed header closes the connection");
            return;
        }
        if (!*next) {
            check(!header || buffered.size() < modbus::mbap_length - 1U + length,
                  "more bytes are awaited only for an unfinished request");
            check(buffered.size() < modbus::max_adu_length,
                  "an unfinished request fits in the server's buffer with room to spare");
            return;
        }
        const auto adu = **next;
        check(adu.data() == buffered.data() && adu.size() == modbus::mbap_length - 1U + length &&
                  adu.size() >= modbus::mbap_length + 1 && adu.size() <= modbus::max_adu_length,
              "a request is the front of the stream, as long as its header says");
        handle(adu);
        comm_loss_ = false;  // §5.3: the first request after a loss reads 1020 as 1, later ones 0
        buffered = buffered.subspan(adu.size());
    }
}

// An exception response: the request's function code with the high bit set, and `expected`.
void check_exception(std::span<const std::uint8_t> adu, const Bytes& pdu, Exception expected) {
    check(pdu.size() == 2, "an exception response is the function code and the exception");
    check(pdu[0] == (adu[modbus::mbap_length] | 0x80),
          "an exception answers the request's function code with the high bit set");
    check(pdu[1] == static_cast<std::uint8_t>(expected), "the planned exception is answered");
}

std::optional<Exception> Harness::write(Unit& unit, const gateway::WritePlan& plan,
                                        std::array<bool, slot_count>& acked) {
    // As LinkScheduler::execute: every change is sent; 0B wins over 04; a reset goes last.
    std::optional<Exception> outcome;
    for (const auto& change : plan.changes) {
        auto& desired = unit.desired[static_cast<std::size_t>(slot(change.module))];
        const auto value = gateway::merged(desired, change);
        const auto answer = devices_.next();
        auto& status = unit.state.status[static_cast<std::size_t>(slot(change.module))];
        if (answer == Answer::ack) {
            acked[static_cast<std::size_t>(slot(change.module))] = true;
            desired = value;
            gateway::store_output(unit.image.tables(), change.module, value);
            status = ModuleStatus::online;
            continue;
        }
        const auto failed = answer == Answer::error_ack ? Exception::server_device_failure
                                                        : Exception::gateway_target_failed;
        status = answer == Answer::error_ack ? ModuleStatus::bad_answer : ModuleStatus::no_answer;
        if (!outcome || failed == Exception::gateway_target_failed) outcome = failed;
    }
    if (plan.reset_counter) {
        const auto answer = devices_.next();
        outcome = answer == Answer::ack         ? std::nullopt
                  : answer == Answer::error_ack ? std::optional(Exception::server_device_failure)
                                                : std::optional(Exception::gateway_target_failed);
        if (answer == Answer::ack) unit.state.status[0] = ModuleStatus::online;
    }
    return outcome;
}

void check_write_plan(const Unit& unit, const modbus::Request& request,
                      const gateway::WritePlan& plan) {
    check(request.write, "only a write has a write plan");
    check(unit.state.port_open || (plan.changes.empty() && !plan.reset_counter),
          "nothing is sent to a closed port");
    if (unit.state.kind == gateway::UnitKind::id2) {
        check(plan.changes.empty(), "an ID-2 has no outputs");
        check(plan.reset_counter == (modbus::write_value(request, 0) != 0),
              "ID-2 coil 0: 1 resets the counter, 0 does nothing");
        return;
    }
    check(!plan.reset_counter, "an ioport unit has no counter");
    check(!plan.changes.empty(), "a write to an ioport unit sends a command");
    int covered = 0;
    for (const auto& change : plan.changes) {
        const auto status = unit.state.status[static_cast<std::size_t>(slot(change.module))];
        check(is_output(change.module.type) && status != ModuleStatus::not_configured,
              "a command goes to a configured output module");
        check((change.value & ~change.mask) == 0, "a change sets only bits of its mask");
        check(validate_output_value(change.module.type, change.value).has_value() ||
                  change.mask != 0xFFFF,
              "a whole value is one the module can be commanded");
        covered += request.table == Table::coils ? std::popcount(change.mask) : 1;
    }
    check(covered == request.quantity, "the changes cover every address written, once");
}

// The slot of an output module by its holding register, as §2 numbers them: slot = (type
// letter - 'a') * 8 + number, dom16 'b' at registers 0-7, rgbdm 'f' 8-15, mux8m 'i' 16-23.
int slot_of_register(int reg) {
    constexpr std::array<int, 3> type_index{1, 5, 8};
    return type_index[static_cast<std::size_t>(reg / 8)] * 8 + reg % 8;
}

// The outputs as they must be after `request` (nullptr: a request that writes nothing), given
// which modules acknowledged their command: a written coil or register takes the value written,
// and a dom16's coils and register change together; nothing else changes.
Image expected_outputs(Image image, const modbus::Request* request,
                       const std::array<bool, slot_count>& acked) {
    if (request == nullptr) return image;
    for (std::size_t i = 0; i < request->quantity; ++i) {
        const int address = request->address + static_cast<int>(i);
        const auto value = modbus::write_value(*request, i);
        const int reg = request->table == Table::coils ? address / 16 : address;
        if (!acked[static_cast<std::size_t>(slot_of_register(reg))]) continue;
        auto& word = image.holding_registers[static_cast<std::size_t>(reg)];
        if (request->table == Table::coils) {
            image.coils[static_cast<std::size_t>(address)] = value != 0 ? 1 : 0;
            const auto bit = static_cast<std::uint16_t>(1U << (address % 16));
            word = static_cast<std::uint16_t>(value != 0 ? word | bit : word & ~bit);
            continue;
        }
        word = value;
        if (reg < 8)
            for (std::size_t k = 0; k < 16; ++k)
                image.coils[16 * static_cast<std::size_t>(reg) + k] = value >> k & 1U;
    }
    return image;
}

void Harness::check_image(const Unit& unit, const Image& before, const modbus::Request* request,
                          const std::array<bool, slot_count>& acked) {
    const auto after = snapshot(unit.image.tables());
    check(after.discrete_inputs == before.discrete_inputs &&
              after.input_registers == before.input_registers,
          "a write changes no input, nor does an exception");
    if (unit.state.kind == gateway::UnitKind::id2) {
        check(after.coils == before.coils && after.coils[0] == 0, "ID-2 coil 0 reads 0");
        return;
    }
    const auto expected = expected_outputs(before, request, acked);
    check(after.coils == expected.coils, "the coils are as written where the device acked");
    check(after.holding_registers == expected.holding_registers,
          "the registers are as written where the device acked");
    for (int reg = 0; reg < static_cast<int>(gateway::holding_register_count); ++reg)
        check(after.holding_registers[static_cast<std::size_t>(reg)] ==
                  unit.desired[static_cast<std::size_t>(slot_of_register(reg))],
              "an output's register is its last confirmed value");
    for (std::size_t n = 0; n < modules_per_type; ++n) {
        std::uint16_t coils = 0;
        for (std::size_t k = 0; k < 16; ++k)
            coils = static_cast<std::uint16_t>(coils | (after.coils[16 * n + k] & 1U) << k);
        check(coils == after.holding_registers[n], "a dom16's coils and holding register agree");
    }
}

bool same_image(const Image& a, const Image& b) {
    return a.coils == b.coils && a.discrete_inputs == b.discrete_inputs &&
           a.holding_registers == b.holding_registers && a.input_registers == b.input_registers;
}

// §5.1 counted as the spec words it: every response to a known unit is a request, one with the
// high bit set an exception; a write (FC 05, 06, 15, 16, 23) answered normally is confirmed, one
// answered 04 or 0B failed.
void count_as_spec(gateway::Traffic& counted, std::uint8_t function, const Bytes& reply) {
    constexpr std::array<std::uint8_t, 5> writes{0x05, 0x06, 0x0F, 0x10, 0x17};
    const bool write = std::find(writes.begin(), writes.end(), function) != writes.end();
    ++counted.requests;
    if ((reply[0] & 0x80U) == 0) {
        if (write) ++counted.writes_confirmed;
        return;
    }
    ++counted.exceptions;
    if (write && (reply[1] == 0x04 || reply[1] == 0x0B)) ++counted.writes_failed;
}

bool same_traffic(const gateway::Traffic& a, const gateway::Traffic& b) {
    return a.requests == b.requests && a.exceptions == b.exceptions &&
           a.writes_confirmed == b.writes_confirmed && a.writes_failed == b.writes_failed;
}

// FC 43 / MEI 14 (gateway.md §5.2, MAP v1.1b3 §6.21) against the unit's objects.
void check_identification(std::span<const std::uint8_t> adu, const Bytes& reply,
                          const modbus::DeviceIdentity& identity) {
    constexpr std::size_t max_pdu = 253;
    constexpr std::size_t header = 7;  // 2B 0E code conformity more next count
    constexpr std::size_t last_regular = 6;
    const auto pdu = adu.subspan(modbus::mbap_length);
    if (pdu.size() < 2 || pdu[1] != 0x0E) {
        check_exception(adu, reply, Exception::illegal_function);  // another MEI type
        return;
    }
    const std::uint8_t code = pdu.size() == 4 ? pdu[2] : 0;
    if (code < 1 || code > 4) {
        check_exception(adu, reply, Exception::illegal_data_value);
        return;
    }
    const std::size_t asked = pdu[3];
    if (code == 4 && asked > last_regular) {
        check_exception(adu, reply, Exception::illegal_data_address);
        return;
    }
    check(reply.size() >= header && reply.size() <= max_pdu,
          "an identification response is a header and objects, within a PDU");
    check(reply[0] == 0x2B && reply[1] == 0x0E && reply[2] == code && reply[3] == 0x82,
          "an identification response is 2B 0E, the code asked for and conformity level 82");
    const auto more = reply[4];
    const std::size_t next = reply[5];
    check(more == 0x00 || more == 0xFF, "more follows is 00 or FF");
    std::size_t objects = 0;
    std::size_t first = 0;
    std::size_t previous = 0;
    for (std::size_t at = header; at < reply.size();) {
        check(at + 2 <= reply.size(), "an object has its id and its length");
        const std::size_t id = reply[at];
        const std::size_t length = reply[at + 1];
        check(at + 2 + length <= reply.size(), "an object is as long as its length says");
        check(id <= last_regular && (objects == 0 || id > previous),
              "object ids are at most 6 and increase");
        check(objects == 0 || id == previous + 1, "a stream's objects are consecutive");
        const auto& value = identity[id];
        check(length == value.size() &&
                  std::equal(value.begin(), value.end(), reply.begin() + at + 2),
              "an object is the unit's value");
        if (objects == 0) first = id;
        previous = id;
        ++objects;
        at += 2 + length;
    }
    check(objects == reply[6], "the number of objects is the objects'");
    if (code == 4) {
        check(objects == 1 && first == asked && more == 0 && next == 0,
              "individual access answers the one object asked for");
        return;
    }
    const std::size_t last = code == 1 ? 2 : last_regular;  // basic 00-02; regular, extended 00-06
    check(objects >= 1 && first == (asked <= last ? asked : 0),
          "a stream starts at the object asked for, or at 00 when it is not of the category");
    if (more == 0)
        check(previous == last && next == 0, "a whole stream ends at its category's last object");
    else
        check(previous < last && next == previous + 1 &&
                  reply.size() + 2 + identity[next].size() > max_pdu,
              "more follows exactly when the next object does not fit, and names it");
}

void Harness::check_read_back(const Unit& unit, const modbus::Request& request,
                              std::span<const std::uint8_t> adu, const Bytes& reply,
                              const gateway::Plan& read) const {
    // §3.3: a read touching a configured module that is not online answers 0B with stale:
    // exception; FC 23's read part is such a read, decided after its write.
    bool stale = false;
    for (int reg = request.read_address; reg < request.read_address + request.read_quantity;
         ++reg) {
        const auto status = unit.state.status[static_cast<std::size_t>(slot_of_register(reg))];
        stale = stale || (status != ModuleStatus::not_configured && status != ModuleStatus::online);
    }
    if (stale && policy_.stale == gateway::Stale::exception) {
        check_exception(adu, reply, Exception::gateway_target_failed);
        return;
    }
    const auto* plan = std::get_if<gateway::ReadPlan>(&read);
    check(plan != nullptr && !plan->diagnostics, "FC 23's read part reads outputs");
    const auto image = snapshot(unit.image.tables());
    const std::size_t count = std::size_t{request.read_quantity} * 2;
    check(reply.size() == 2 + count && reply[0] == 0x17 && reply[1] == count,
          "FC 23 answers 0x17, a byte count of twice the read quantity and the registers");
    for (std::size_t i = 0; i < request.read_quantity; ++i)
        check(be16(reply, 2 + 2 * i) == image.holding_registers[request.read_address + i],
              "FC 23 reads the holding registers as they are after its write");
}

void Harness::check_front(const gateway::Traffic& counted, std::uint16_t address,
                          std::uint16_t quantity, const Bytes& reply) const {
    constexpr int first = 1010;
    constexpr int last = 1020;
    std::array<std::uint16_t, last - first + 1> expected{};
    const auto u32 = [&](std::size_t at, std::uint64_t value) {
        const auto wrapped = static_cast<std::uint32_t>(value);
        const auto high = static_cast<std::uint16_t>(wrapped >> 16U);
        const auto low = static_cast<std::uint16_t>(wrapped);
        const bool big = word_order_ == gateway::WordOrder::big;
        expected[at] = big ? high : low;
        expected[at + 1] = big ? low : high;
    };
    u32(0, counted.requests);
    u32(2, counted.exceptions);
    u32(4, counted.writes_confirmed);
    u32(6, counted.writes_failed);
    expected[8] = 1;  // the harness's one connection
    expected[9] = static_cast<std::uint16_t>(std::min<std::int64_t>(
        std::chrono::duration_cast<std::chrono::seconds>(since_previous_).count(), 0xFFFF));
    expected[10] = comm_loss_ ? 1 : 0;
    const int from = std::max<int>(first, address);
    const int to = std::min<int>(last, address + quantity - 1);
    for (int a = from; a <= to; ++a) {
        const auto value = be16(reply, 2 + 2 * static_cast<std::size_t>(a - address));
        check(value == expected[static_cast<std::size_t>(a - first)],
              "1010-1020 read the traffic as it was before this request");
        check(a != last || value <= 1, "1020 is 0 or 1");
    }
}

void Harness::check_metrics(const Unit* unit, std::uint8_t function, const Bytes& reply) {
    const std::pair key{unit_label_as_spec(unit), function_label_as_spec(function)};
    const auto before = count_of(metrics_.requests(), key);
    const bool exception = (reply[0] & 0x80U) != 0;
    const std::pair exception_key{key.first, exception ? int{reply[1]} : 0};
    const auto exceptions_before = count_of(metrics_.exceptions(), exception_key);
    metrics_.count(unit != nullptr ? unit->link->unit_id : -1, function, reply);
    check(count_of(metrics_.requests(), key) == before + 1,
          "a response counts under its configured unit or other, and §3.5's code or other");
    const auto series = (units_.size() + 1) * 11;
    check(metrics_.requests().size() <= series && metrics_.exceptions().size() <= series,
          "at most (configured units + 1) x 11 series");
    if (!exception) return;
    constexpr std::array<std::uint8_t, 7> codes{0x01, 0x02, 0x03, 0x04, 0x06, 0x0A, 0x0B};
    check(std::find(codes.begin(), codes.end(), reply[1]) != codes.end(),
          "an exception code is one of the server's, never the client's");
    check(count_of(metrics_.exceptions(), exception_key) == exceptions_before + 1,
          "an exception counts under its unit and its code");
}

void Harness::handle(std::span<const std::uint8_t> adu) {
    ++handled_;
    // 16384.000123 s more before each request: 1019 reads 16384, 32768, 49152, then 65535.
    since_previous_ =
        std::chrono::microseconds(static_cast<std::int64_t>(handled_) * 16'384'000'123);
    const daemon::PaddedRequest request(adu);
    const auto transaction = be16(adu, 0);
    const auto unit_id = adu[modbus::mbap_length - 1];
    const auto pdu = adu.subspan(modbus::mbap_length);
    Unit* unit = by_id_[unit_id];

    // What was sent, and the checks every response passes; a response for a known unit is
    // counted, as the server counts it when sent.
    const auto answered = [&](const Result<Bytes>& built) {
        check(built.has_value(), "libmodbus builds the response");
        const auto& bytes = *built;
        check(bytes.size() >= modbus::mbap_length + 2, "a response has a header and a PDU");
        check(be16(bytes, 0) == transaction, "the transaction id is echoed");
        check(be16(bytes, 2) == 0, "the protocol id is 0");
        check(be16(bytes, 4) == bytes.size() - (modbus::mbap_length - 1),
              "the length field counts the unit id and the PDU");
        check(bytes[modbus::mbap_length - 1] == unit_id, "the unit id is echoed");
        Bytes reply(bytes.begin() + modbus::mbap_length, bytes.end());
        check_metrics(unit, pdu[0], reply);
        if (unit != nullptr) {
            count_as_spec(unit->counted, pdu[0], reply);
            const auto& traffic = metrics_.traffic(unit->link->unit_id);
            check(same_traffic(traffic, unit->counted), "responses count as gateway.md §5.1 says");
            check(traffic.requests >= traffic.exceptions, "requests >= exceptions");
            check(traffic.writes_confirmed + traffic.writes_failed <= traffic.requests,
                  "confirmed + failed writes <= requests");
        }
        return reply;
    };

    if (unit == nullptr) {
        const auto reply =
            answered(replies_->exception(request, Exception::gateway_path_unavailable));
        check_exception(adu, reply, Exception::gateway_path_unavailable);
        return;
    }
    const auto before = snapshot(unit->image.tables());

    // Identification is the unit's: decided before any plan, whatever the port or read_only.
    if (pdu[0] == modbus::encapsulated_interface_transport) {
        const auto identification = modbus::read_device_identification(pdu, unit->identity);
        const auto reply = identification
                               ? answered(daemon::ReplyBuilder::framed(request, *identification))
                               : answered(replies_->exception(request, identification.error()));
        check_identification(adu, reply, unit->identity);
        check(same_image(snapshot(unit->image.tables()), before),
              "device identification changes nothing in the image");
        return;
    }

    const auto plan = gateway::plan(unit->state, policy_, pdu);
    const auto parsed = modbus::parse_request(pdu);

    if (const auto* exception = std::get_if<Exception>(&plan)) {
        const bool supported = parsed.has_value();
        check(supported == (*exception != Exception::illegal_function ||
                            (policy_.read_only && parsed && parsed->write)),
              "01 answers an unsupported function, or a write when read-only");
        check(*exception != Exception::illegal_data_address || parsed->write ||
                  !inside_one_block(unit->state.kind, parsed->table, parsed->address,
                                    parsed->quantity),
              "02 answers a read only when it does not lie inside one block of gateway.md §4");
        const auto reply = answered(replies_->exception(request, *exception));
        check_exception(adu, reply, *exception);
        check_image(*unit, before, nullptr, {});
        return;
    }
    // Planned: the request is supported, well formed, within the limits and inside one block.
    check(parsed.has_value() && parsed->well_formed && !modbus::check_limits(*parsed),
          "a planned request is well formed and within the Modbus limits");
    check(inside_one_block(unit->state.kind, parsed->table, parsed->address, parsed->quantity),
          "a planned request lies inside one block of gateway.md §4");
    check(!policy_.read_only || !parsed->write, "read-only plans no write");
    const bool read_write = parsed->function == modbus::Function::read_write_multiple_registers;
    if (read_write) {
        const auto in_holding = [](int first, int count) {
            return first + count - 1 <= ioport_blocks.back().last;
        };
        check(unit->state.kind == gateway::UnitKind::ioport &&
                  parsed->table == Table::holding_registers &&
                  in_holding(parsed->address, parsed->quantity) &&
                  in_holding(parsed->read_address, parsed->read_quantity),
              "FC 23's write and read ranges lie in the holding registers 0-23");
    }

    if (const auto* read = std::get_if<gateway::ReadPlan>(&plan)) {
        check(!parsed->write, "only a read has a read plan");
        check(read->diagnostics == in_diagnostics(parsed->table, parsed->address),
              "diagnostics are refreshed exactly for reads of them");
        const auto counted = unit->counted;  // before this request: it does not count itself
        if (read->diagnostics) {
            refresh_diagnostics(*unit);
            gateway::store_front(
                unit->image.tables(),
                {metrics_.traffic(unit->link->unit_id), 1, since_previous_, comm_loss_},
                word_order_);
        }
        const auto reply = answered(replies_->reply(request, unit->image.mapping()));
        const auto image = snapshot(unit->image.tables());
        const bool bits = parsed->table == Table::coils || parsed->table == Table::discrete_inputs;
        const std::size_t count = bits ? (parsed->quantity + 7U) / 8U : parsed->quantity * 2U;
        check(reply.size() == 2 + count && reply[0] == pdu[0] && reply[1] == count,
              "a read answers its function code, the byte count and the values");
        for (std::size_t i = 0; i < parsed->quantity; ++i) {
            const std::size_t at = parsed->address + i;
            if (bits) {
                const std::span<const std::uint8_t> table =
                    parsed->table == Table::coils ? std::span<const std::uint8_t>(image.coils)
                                                  : image.discrete_inputs;
                check((reply[2 + i / 8] >> (i % 8) & 1U) == table[at], "a bit read is the image's");
            } else {
                const std::span<const std::uint16_t> table =
                    parsed->table == Table::holding_registers
                        ? std::span<const std::uint16_t>(image.holding_registers)
                        : image.input_registers;
                check(be16(reply, 2 + 2 * i) == table[at], "a register read is the image's");
            }
        }
        if (read->diagnostics && parsed->table == Table::input_registers)
            check_front(counted, parsed->address, parsed->quantity, reply);
        auto expected = before;
        if (read->diagnostics) take_diagnostics(expected, image);
        check(same_image(image, expected),
              "a read changes only diagnostics, and only when it reads them");
        return;
    }

    const auto& write_plan = std::get<gateway::WritePlan>(plan);
    check_write_plan(*unit, *parsed, write_plan);
    check(read_write ? write_plan.read_address == parsed->read_address &&
                           write_plan.read_quantity == parsed->read_quantity
                     : write_plan.read_quantity == 0,
          "only FC 23 reads after its write, the range it asked for");
    std::array<bool, slot_count> acked{};
    const auto failed = write(*unit, write_plan, acked);
    check_image(*unit, before, &*parsed, acked);
    if (failed) {
        // FC 23 too: a failed write answers its exception and reads nothing.
        const auto reply = answered(replies_->exception(request, *failed));
        check_exception(adu, reply, *failed);
        return;
    }
    if (read_write) {
        const auto read =
            gateway::read_back(unit->state, policy_, parsed->read_address, parsed->read_quantity);
        const auto* exception = std::get_if<Exception>(&read);
        const auto reply = exception ? answered(replies_->exception(request, *exception))
                                     : answered(daemon::ReplyBuilder::read_back(
                                           request, parsed->read_address, parsed->read_quantity,
                                           *unit->image.mapping()));
        check_read_back(*unit, *parsed, adu, reply, read);
        check_image(*unit, before, &*parsed, acked);
        return;
    }
    const auto reply = answered(replies_->reply(request, scratch_.get()));
    // FC05 and FC06 echo the request; FC15 and FC16 its function code, address and quantity.
    const bool single = pdu[0] == 0x05 || pdu[0] == 0x06;
    const auto echoed = pdu.first(single ? pdu.size() : 5);
    check(std::equal(reply.begin(), reply.end(), echoed.begin(), echoed.end()),
          "a write's response echoes the request");
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using ioport::fuzz::scenario_length;
    if (size < scenario_length) return 0;
    ioport::fuzz::Harness harness(
        std::span<const std::uint8_t, scenario_length>(data, scenario_length));
    harness.serve({data + scenario_length, size - scenario_length});
    return 0;
}
