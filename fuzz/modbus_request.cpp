// Fuzz target: the Modbus request path, from the bytes of a client's TCP stream to the responses
// and the changes of the process image, against a configured map.
//
// It runs what ModbusServer::serve, ::answer and ::write run, minus the sockets and the serial
// links: modbus::next_adu frames the stream, the unit is looked up as set_units() arranges them,
// gateway::plan() decides, a write's changes are merged and stored as LinkScheduler::apply does
// once the device answered, and libmodbus builds the response through the daemon's own
// ReplyBuilder.
//
// Input: a scenario of `scenario_length` bytes, then the stream.
//   byte 0     bit 0 read_only, bit 1 stale: hold, bit 2 only the hub is configured (so unit ids
//              0 and 255 reach it too), bit 3 the hub's port is closed, bit 4 the ID-2's port is
//              closed, bit 5 word_order: little
//   bytes 1-8  two bits per configured module, in configuration order (the ID-2 last): its
//              status, 0 online, 1 no answer, 2 bad answer, 3 not polled yet
//   bytes 9-10 two bits per device command sent for a write, cycling: 0 and 1 acknowledged,
//              2 error ack, 3 no answer
// All zeros is the everyday case: every port open, every module online, every command acked.
//
// Invariants, from gateway.md rather than from the code under test: each response echoes the
// request's transaction id and unit id, has a consistent length and is one of the responses the
// request allows (the exception planned, with the high bit set, or the normal response whose
// values are the image's); a planned request lies inside one block of §4; the image changes
// only at the outputs of modules whose device acknowledged a write, to the merged value, and a
// dom16's coils and register always agree; an unfinished request always fits the server's
// buffer.
#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <cstring>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/modbus_reply.hpp"
#include "fuzz/fuzz.hpp"
#include "protocol/gateway_map.hpp"
#include "protocol/modbus.hpp"

namespace ioport::fuzz {
namespace {

using daemon::Bytes;
using gateway::ModuleStatus;
using modbus::Exception;
using modbus::Table;

constexpr std::size_t scenario_length = 11;

// Two modules of every type, a dom16 pair side by side (one write can span both), and an ID-2.
constexpr std::string_view configuration = R"(
modbus:
  listen: "127.0.0.1:1502"
links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    unit_id: 1
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

std::uint16_t be16(std::span<const std::uint8_t> bytes, std::size_t at) {
    return static_cast<std::uint16_t>(bytes[at] << 8 | bytes[at + 1]);
}

// --- The map, as gateway.md §2 and §4 write it ----------------------------------------------

struct Block {
    Table table;
    int first;
    int last;
};

constexpr std::array<Block, 4> diagnostics_blocks{{{Table::input_registers, 1000, 1009},
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
};

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

    gateway::Policy policy_;
    gateway::WordOrder word_order_;
    std::vector<std::unique_ptr<Unit>> units_;
    std::array<Unit*, 256> by_id_{};
    Devices devices_;
    daemon::Mapping scratch_ = daemon::scratch_mapping();
    std::unique_ptr<daemon::ReplyBuilder> replies_;
    std::uint64_t handled_ = 0;
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
        gateway::store_reading(tables, module.address, reading, order);
    }
}

Harness::Harness(std::span<const std::uint8_t, scenario_length> scenario)
    : policy_{(scenario[0] & 1U) != 0,
              (scenario[0] & 2U) != 0 ? gateway::Stale::hold : gateway::Stale::exception},
      word_order_((scenario[0] & 32U) != 0 ? gateway::WordOrder::little : gateway::WordOrder::big),
      devices_(be16(scenario, 9)) {
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

void Harness::handle(std::span<const std::uint8_t> adu) {
    ++handled_;
    const daemon::PaddedRequest request(adu);
    const auto transaction = be16(adu, 0);
    const auto unit_id = adu[modbus::mbap_length - 1];
    const auto pdu = adu.subspan(modbus::mbap_length);
    Unit* unit = by_id_[unit_id];

    // What was sent, and the checks every response passes.
    const auto answered = [&](const Result<Bytes>& built) {
        check(built.has_value(), "libmodbus builds the response");
        const auto& bytes = *built;
        check(bytes.size() >= modbus::mbap_length + 2, "a response has a header and a PDU");
        check(be16(bytes, 0) == transaction, "the transaction id is echoed");
        check(be16(bytes, 2) == 0, "the protocol id is 0");
        check(be16(bytes, 4) == bytes.size() - (modbus::mbap_length - 1),
              "the length field counts the unit id and the PDU");
        check(bytes[modbus::mbap_length - 1] == unit_id, "the unit id is echoed");
        return Bytes(bytes.begin() + modbus::mbap_length, bytes.end());
    };

    if (unit == nullptr) {
        const auto reply =
            answered(replies_->exception(request, Exception::gateway_path_unavailable));
        check_exception(adu, reply, Exception::gateway_path_unavailable);
        return;
    }
    const auto before = snapshot(unit->image.tables());
    const auto plan = gateway::plan(unit->state, policy_, pdu);
    const auto parsed = modbus::parse_request(pdu);

    if (const auto* exception = std::get_if<Exception>(&plan)) {
        const bool supported = parsed.has_value();
        check(supported == (*exception != Exception::illegal_function ||
                            (policy_.read_only && parsed && parsed->write)),
              "01 answers an unsupported function, or a write when read-only");
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

    if (const auto* read = std::get_if<gateway::ReadPlan>(&plan)) {
        check(!parsed->write, "only a read has a read plan");
        check(read->diagnostics == in_diagnostics(parsed->table, parsed->address),
              "diagnostics are refreshed exactly for reads of them");
        if (read->diagnostics) refresh_diagnostics(*unit);
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
        auto expected = before;
        if (read->diagnostics) take_diagnostics(expected, image);
        check(image.coils == expected.coils &&
                  image.holding_registers == expected.holding_registers &&
                  image.discrete_inputs == expected.discrete_inputs &&
                  image.input_registers == expected.input_registers,
              "a read changes only diagnostics, and only when it reads them");
        return;
    }

    const auto& write_plan = std::get<gateway::WritePlan>(plan);
    check_write_plan(*unit, *parsed, write_plan);
    std::array<bool, slot_count> acked{};
    const auto failed = write(*unit, write_plan, acked);
    check_image(*unit, before, &*parsed, acked);
    if (failed) {
        const auto reply = answered(replies_->exception(request, *failed));
        check_exception(adu, reply, *failed);
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
