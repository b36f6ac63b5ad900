#include "protocol/gateway_map.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <optional>
#include <string_view>

namespace ioport::gateway {
namespace {

using modbus::Exception;
using modbus::Request;
using modbus::Table;

// What an address range of a unit holds. The order matters: module data first, then the ID-2
// reset coil (a command, never stale data), then the diagnostics.
enum class Content : std::uint8_t {
    input_bit,    // dim16/lim16 input k
    input_word,   // dim16/lim16, the 16 inputs as one word
    raw,          // analog channel, raw 0-65535
    engineering,  // analog channel, float32
    output_bit,   // dom16 output k
    output_word,  // dom16 word, rgbdm colour, mux8m (pos << 8) | neg
    stop_input,   // ID-2
    counter,      // ID-2
    reset,        // ID-2 coil 0
    link,         // input registers 1000-1009
    status,       // input register 1100 + slot
    age,          // input register 1200 + slot
    online,       // discrete input 1000 + slot
};

constexpr bool is_data(Content content) {
    return content <= Content::counter;
}
constexpr bool is_diagnostics(Content content) {
    return content >= Content::link;
}

constexpr int no_slot = -1;

// A run of addresses with one meaning, owned slot by slot: slot first_slot + i holds the
// per_slot addresses from first + i * per_slot, one channel value every per_channel addresses.
// Blocks (gateway.md §4) are the maximal runs of regions of one table that meet.
struct Region {
    Table table = Table::coils;
    int first = 0;
    Content content = Content::input_bit;
    int first_slot = no_slot;
    int slots = 1;
    int per_slot = 1;
    int per_channel = 1;
    constexpr int end() const { return first + slots * per_slot; }
    constexpr bool owns(int slot) const {
        return first_slot != no_slot && slot >= first_slot && slot < first_slot + slots;
    }
    constexpr int base(int slot) const { return first + (slot - first_slot) * per_slot; }
    constexpr int channels() const { return per_slot / per_channel; }
};

constexpr Region module_region(Table table, int first, Content content, ModuleType type,
                               int per_slot = 1, int per_channel = 1) {
    return {table, first, content, slot({type, 0}), modules_per_type, per_slot, per_channel};
}

constexpr int bits_per_word = 16;
constexpr int analog_channels = 3;
constexpr int float_words = 2;
constexpr int analog_float_words = analog_channels * float_words;

constexpr std::array ioport_data{
    module_region(Table::coils, 0, Content::output_bit, ModuleType::dom16, bits_per_word),
    module_region(Table::discrete_inputs, 0, Content::input_bit, ModuleType::dim16, bits_per_word),
    module_region(Table::discrete_inputs, 128, Content::input_bit, ModuleType::lim16,
                  bits_per_word),
    module_region(Table::holding_registers, 0, Content::output_word, ModuleType::dom16),
    module_region(Table::holding_registers, 8, Content::output_word, ModuleType::rgbdm),
    module_region(Table::holding_registers, 16, Content::output_word, ModuleType::mux8m),
    module_region(Table::input_registers, 0, Content::input_word, ModuleType::dim16),
    module_region(Table::input_registers, 8, Content::input_word, ModuleType::lim16),
    module_region(Table::input_registers, 16, Content::raw, ModuleType::acm3p, analog_channels),
    module_region(Table::input_registers, 40, Content::raw, ModuleType::acm3c, analog_channels),
    module_region(Table::input_registers, 64, Content::raw, ModuleType::dccim),
    module_region(Table::input_registers, 72, Content::raw, ModuleType::dcvim),
    module_region(Table::input_registers, 200, Content::engineering, ModuleType::acm3p,
                  analog_float_words, float_words),
    module_region(Table::input_registers, 248, Content::engineering, ModuleType::acm3c,
                  analog_float_words, float_words),
    module_region(Table::input_registers, 296, Content::engineering, ModuleType::dccim, float_words,
                  float_words),
    module_region(Table::input_registers, 312, Content::engineering, ModuleType::dcvim, float_words,
                  float_words),
};

// The ID-2 device is slot 0.
constexpr std::array id2_data{
    Region{Table::coils, 0, Content::reset, 0},
    Region{Table::discrete_inputs, 0, Content::stop_input, 0},
    Region{Table::input_registers, 0, Content::counter, 0},
};

constexpr int link_state_address = 1000;
constexpr int cycle_time_address = 1001;
constexpr int cycles_address = 1002;
constexpr int ok_address = 1004;
constexpr int failed_address = 1006;
constexpr int opens_address = 1008;
// §5.1, the Modbus server's figures.
constexpr int requests_address = 1010;
constexpr int exceptions_address = 1012;
constexpr int writes_confirmed_address = 1014;
constexpr int writes_failed_address = 1016;
constexpr int connections_address = 1018;
constexpr int since_previous_address = 1019;
constexpr int comm_loss_address = 1020;
constexpr int link_registers = 21;
constexpr int status_address = 1100;
constexpr int age_address = 1200;
constexpr int online_address = 1000;

constexpr std::array diagnostics_regions{
    Region{Table::discrete_inputs, online_address, Content::online, 0, slot_count},
    Region{Table::input_registers, link_state_address, Content::link, no_slot, 1, link_registers},
    Region{Table::input_registers, status_address, Content::status, 0, slot_count},
    Region{Table::input_registers, age_address, Content::age, 0, slot_count},
};

template <std::size_t A, std::size_t B>
constexpr std::array<Region, A + B> join(const std::array<Region, A>& a,
                                         const std::array<Region, B>& b) {
    std::array<Region, A + B> out{};
    std::copy(a.begin(), a.end(), out.begin());
    std::copy(b.begin(), b.end(), out.begin() + A);
    return out;
}

constexpr auto ioport_regions = join(ioport_data, diagnostics_regions);
constexpr auto id2_regions = join(id2_data, diagnostics_regions);

constexpr std::size_t table_size(Table table) {
    switch (table) {
        case Table::coils:
            return coil_count;
        case Table::discrete_inputs:
            return discrete_input_count;
        case Table::holding_registers:
            return holding_register_count;
        case Table::input_registers:
            return input_register_count;
    }
    return 0;
}
template <std::size_t N>
constexpr bool fit(const std::array<Region, N>& list) {
    for (const auto& region : list)
        if (static_cast<std::size_t>(region.end()) > table_size(region.table)) return false;
    return true;
}
// The store functions index the tables by these regions without checking.
static_assert(fit(ioport_regions) && fit(id2_regions));

std::span<const Region> regions(UnitKind kind) {
    if (kind == UnitKind::ioport) return ioport_regions;
    return id2_regions;
}

struct Location {
    const Region* region = nullptr;
    int offset = 0;  // from region->first
    Content content() const { return region->content; }
    int slot() const { return region->first_slot + offset / region->per_slot; }
    int channel() const { return offset % region->per_slot / region->per_channel; }
};

std::optional<Location> locate(UnitKind kind, Table table, int address) {
    for (const auto& region : regions(kind))
        if (region.table == table && address >= region.first && address < region.end())
            return Location{&region, address - region.first};
    return std::nullopt;
}

// The end of the block that `list[i]` begins or continues: the regions of its table that meet.
template <std::size_t N>
constexpr std::array<int, N> block_ends(const std::array<Region, N>& list) {
    std::array<int, N> ends{};
    for (std::size_t i = 0; i < N; ++i) {
        int end = list[i].end();
        for (bool grew = true; grew;) {
            grew = false;
            for (const auto& next : list)
                if (next.table == list[i].table && end >= next.first && end < next.end()) {
                    end = next.end();
                    grew = true;
                }
        }
        ends[i] = end;
    }
    return ends;
}

// Computed once: walking the regions on every request was a fifth of a read's CPU time in user
// space (IR 0-15 takes seven lookups to find that its block ends at 80).
constexpr auto ioport_block_ends = block_ends(ioport_regions);
constexpr auto id2_block_ends = block_ends(id2_regions);

int block_end(UnitKind kind, const Region& region) {
    const auto index = static_cast<std::size_t>(&region - regions(kind).data());
    return kind == UnitKind::ioport ? ioport_block_ends[index] : id2_block_ends[index];
}

// The request's first address, when the whole range lies inside one block.
std::optional<Location> locate_range(UnitKind kind, const Request& request) {
    const auto start = locate(kind, request.table, request.address);
    if (!start || request.address + request.quantity > block_end(kind, *start->region))
        return std::nullopt;
    return start;
}

// Where each address of a write lies; the range is inside one block.
std::vector<Location> locate_each(UnitKind kind, const Request& request) {
    std::vector<Location> where;
    where.reserve(request.quantity);
    for (int i = 0; i < request.quantity; ++i)
        if (const auto at = locate(kind, request.table, request.address + i)) where.push_back(*at);
    return where;
}

ModuleStatus status_at(const UnitState& unit, const Location& at) {
    return unit.status[static_cast<std::size_t>(at.slot())];
}

// Region by region and slot by slot, not address by address: a read of 2000 bits is on the
// request path of every client and must not cost 2000 lookups.
bool stale(const UnitState& unit, const Request& request) {
    const int first = request.address;
    const int end = request.address + request.quantity;
    for (const auto& region : regions(unit.kind)) {
        if (region.table != request.table || !is_data(region.content)) continue;
        const int lo = std::max(first, region.first);
        const int hi = std::min(end, region.end());
        if (lo >= hi) continue;
        const int last_slot = region.first_slot + (hi - 1 - region.first) / region.per_slot;
        for (int s = region.first_slot + (lo - region.first) / region.per_slot; s <= last_slot;
             ++s) {
            const auto status = unit.status[static_cast<std::size_t>(s)];
            if (status != ModuleStatus::not_configured && status != ModuleStatus::online)
                return true;
        }
    }
    return false;
}

Plan plan_read(const UnitState& unit, const Policy& policy, const Request& request,
               const Location& start) {
    if (policy.stale == Stale::exception && stale(unit, request))
        return Exception::gateway_target_failed;
    return ReadPlan{is_diagnostics(start.content())};
}

bool unconfigured(const UnitState& unit, std::span<const Location> where) {
    return std::any_of(where.begin(), where.end(), [&](const Location& at) {
        return is_data(at.content()) && status_at(unit, at) == ModuleStatus::not_configured;
    });
}

bool valid_values(const Request& request, std::span<const Location> where) {
    for (std::size_t i = 0; i < where.size(); ++i) {
        if (where[i].content() != Content::output_word) continue;
        const auto type = module_at_slot(where[i].slot()).type;
        if (!validate_output_value(type, modbus::write_value(request, i))) return false;
    }
    return true;
}

// Coils of one dom16 merge into one change, so that one request sends one command per module.
std::vector<OutputChange> output_changes(const Request& request, std::span<const Location> where) {
    std::vector<OutputChange> changes;
    for (std::size_t i = 0; i < where.size(); ++i) {
        const auto module = module_at_slot(where[i].slot());
        const auto value = modbus::write_value(request, i);
        if (changes.empty() || changes.back().module != module) changes.push_back({module, 0, 0});
        auto& change = changes.back();
        if (where[i].content() == Content::output_word) {
            change.mask = 0xFFFF;
            change.value = value;
            continue;
        }
        const auto bit = static_cast<std::uint16_t>(1U << where[i].channel());
        change.mask |= bit;
        if (value != 0) change.value |= bit;
    }
    return changes;
}

// Writing 0 resets nothing, so it needs no device and succeeds even with the port closed.
Plan plan_reset(const UnitState& unit, std::uint16_t value) {
    if (value == 0) return WritePlan{};
    if (!unit.port_open) return Exception::gateway_target_failed;
    return WritePlan{{}, true};
}

Plan plan_write(const UnitState& unit, const Request& request, std::span<const Location> where) {
    if (unconfigured(unit, where)) return Exception::illegal_data_address;
    if (!valid_values(request, where)) return Exception::illegal_data_value;
    if (where.front().content() == Content::reset)
        return plan_reset(unit, modbus::write_value(request, 0));
    if (!unit.port_open) return Exception::gateway_target_failed;
    return WritePlan{output_changes(request, where), false};
}

// --- Storing --------------------------------------------------------------------------------

void put(const Tables& tables, Table table, int address, std::uint16_t value) {
    const auto at = static_cast<std::size_t>(address);
    switch (table) {
        case Table::coils:
            tables.coils[at] = value != 0 ? 1 : 0;
            break;
        case Table::discrete_inputs:
            tables.discrete_inputs[at] = value != 0 ? 1 : 0;
            break;
        case Table::holding_registers:
            tables.holding_registers[at] = value;
            break;
        case Table::input_registers:
            tables.input_registers[at] = value;
            break;
    }
}

void put_words(const Tables& tables, int address, std::array<std::uint16_t, 2> value) {
    put(tables, Table::input_registers, address, value[0]);
    put(tables, Table::input_registers, address + 1, value[1]);
}

std::uint16_t bit(std::uint16_t word, int k) {
    return static_cast<std::uint16_t>(word >> k & 1U);
}

// Calls store(region, address, channel) for the first address of each channel value the
// module has in each region it owns.
template <class Store>
void for_each_channel(ModuleAddress module, Store store) {
    const int s = slot(module);
    for (const auto& region : ioport_data) {
        if (!region.owns(s)) continue;
        for (int c = 0; c < region.channels(); ++c)
            store(region, region.base(s) + c * region.per_channel, c);
    }
}

// Analog channel `channel`; the one-word modules have channel 0 only.
std::uint16_t channel_raw(const Reading& reading, int channel) {
    return reading.raw[static_cast<std::size_t>(channel)];
}

std::uint16_t saturate16(std::uint64_t value) {
    return static_cast<std::uint16_t>(std::min<std::uint64_t>(value, 0xFFFF));
}

// Modbus carries 32 bits; the counters wrap like any u32 counter an integrator already knows.
std::array<std::uint16_t, 2> counter_words(std::uint64_t value, WordOrder order) {
    return words(static_cast<std::uint32_t>(value), order);
}

std::uint16_t tenths_of_ms(std::chrono::microseconds duration) {
    const auto count = std::max<std::chrono::microseconds::rep>(duration.count(), 0);
    return saturate16(static_cast<std::uint64_t>(count / 100));
}

// --- The printable map ----------------------------------------------------------------------

struct LinkField {
    int address;
    std::string_view data_type;
    std::string_view units;
    std::string_view description;
};

constexpr std::array link_fields{
    LinkField{link_state_address, "uint16", "",
              "link state: 0 port not open, 1 open and every module online, 2 open, some "
              "module not online"},
    LinkField{cycle_time_address, "uint16", "0.1 ms",
              "duration of the last complete poll cycle, saturating at 65535"},
    LinkField{cycles_address, "uint32", "", "completed poll cycles"},
    LinkField{ok_address, "uint32", "", "successful transactions"},
    LinkField{failed_address, "uint32", "",
              "failed transactions: timeouts, malformed answers, error acks"},
    LinkField{opens_address, "uint32", "", "times the serial port was (re)opened"},
    LinkField{requests_address, "uint32", "",
              "Modbus requests answered for this unit, exceptions included"},
    LinkField{exceptions_address, "uint32", "", "exception responses sent for this unit"},
    LinkField{writes_confirmed_address, "uint32", "",
              "client writes to this unit answered normally, every device command confirmed"},
    LinkField{writes_failed_address, "uint32", "", "client writes to this unit answered 04 or 0B"},
    LinkField{connections_address, "uint16", "", "Modbus client connections open now"},
    LinkField{since_previous_address, "uint16", "s",
              "seconds since the request before this one (any client, any unit), saturating "
              "at 65535"},
    LinkField{comm_loss_address, "uint16", "",
              "communication loss: 0 normal, 1 outputs were put in their safe state"},
};

std::string colour_description() {
    std::string text = "colour:";
    for (int c = 0; c < colour_count; ++c)
        text += fmt::format("{} {} {}", c == 0 ? "" : ",", c, name(static_cast<Colour>(c)));
    return text;
}

bool multichannel(ModuleType type) {
    return reply_words(type) == analog_channels;
}

std::string output_word_description(ModuleType type) {
    switch (type) {
        case ModuleType::dom16:
            return "outputs 0-15 as one word (bit k = output k)";
        case ModuleType::rgbdm:
            return colour_description();
        case ModuleType::mux8m:
            return "(pos << 8) | neg, each 0-7; pos = neg: all disconnected";
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;  // input modules have no output word
    }
    return "";
}

std::string analog_description(Content content, ModuleType type, int channel,
                               const ChannelTag& tag) {
    const auto prefix = multichannel(type) ? fmt::format("channel {}: ", channel) : std::string{};
    if (content == Content::raw) return prefix + "raw 0-65535";
    auto text = fmt::format("{}raw / 65535 * {:g} {}", prefix, full_scale(type),
                            symbol(engineering_unit(type)));
    if (const auto& s = tag.scale)
        text += fmt::format(", scaled [{:g}, {:g}] to [{:g}, {:g}]", s->in_lo, s->in_hi, s->out_lo,
                            s->out_hi);
    return text;
}

std::string describe(Content content, ModuleType type, int channel, const ModuleTags& tags) {
    switch (content) {
        case Content::input_bit:
            return fmt::format("input {}", channel);
        case Content::input_word:
            return "inputs 0-15 as one word (bit k = input k)";
        case Content::output_bit:
            return fmt::format("output {}", channel);
        case Content::output_word:
            return output_word_description(type);
        case Content::raw:
        case Content::engineering:
            return analog_description(content, type, channel,
                                      tags.channels.at(static_cast<std::size_t>(channel)));
        case Content::stop_input:
            return "machine-stop input";
        case Content::counter:
            return "pulse counter, 0-65535 as the device reports it";
        case Content::reset:
            return "write 1: reset the counter (sends R); reads 0";
        case Content::status:
            return "module status: 0 not configured, 1 online, 2 no answer, 3 bad answer or "
                   "error ack, 4 not polled yet";
        case Content::age:
            return "ms since the module's last good transaction, saturating at 65535";
        case Content::online:
            return "1 while the module is online";
        case Content::link:
            break;
    }
    return "";
}

std::string channel_name(Content content, ModuleType type, int channel) {
    switch (content) {
        case Content::input_bit:
            return fmt::format("i{}", channel);
        case Content::output_bit:
            return fmt::format("o{}", channel);
        case Content::raw:
        case Content::engineering:
            return multichannel(type) ? fmt::format("c{}", channel) : std::string{};
        case Content::input_word:
        case Content::output_word:
        case Content::stop_input:
        case Content::counter:
        case Content::reset:
        case Content::link:
        case Content::status:
        case Content::age:
        case Content::online:
            break;  // one value, no channel
    }
    return "";
}

std::string_view data_type(const Region& region) {
    if (region.table == Table::coils || region.table == Table::discrete_inputs) return "bit";
    return region.content == Content::engineering ? "float32" : "uint16";
}

std::string_view units(Content content, const ModuleTags& tags, int channel) {
    if (content == Content::engineering)
        return tags.channels.at(static_cast<std::size_t>(channel)).unit;
    if (content == Content::age) return "ms";
    return "";
}

std::string_view access(const Region& region) {
    if (region.content == Content::reset) return "write";
    if (region.table == Table::coils || region.table == Table::holding_registers)
        return "read/write";
    return "read";
}

std::string module_name(const UnitMap& unit, int s) {
    if (unit.kind == UnitKind::id2) return "ID-2";
    return to_string(module_at_slot(s));
}

// The tags of the module at slot `s`, every default where the map was given none.
ModuleTags tags_at(const UnitMap& unit, int s) {
    if (unit.kind == UnitKind::id2) return {.name = "ID-2", .channels = {}, .points = {}};
    const auto module = module_at_slot(s);
    const auto at = std::ranges::find(unit.modules, module);
    const auto i = static_cast<std::size_t>(at - unit.modules.begin());
    auto defaults = default_tags(module);
    if (i >= unit.tags.size() || unit.tags[i].channels.size() != defaults.channels.size())
        return defaults;
    return unit.tags[i];
}

// The configured name of a channel or point, "" where it has none.
std::string tag_name(Content content, const ModuleTags& tags, int channel) {
    const auto c = static_cast<std::size_t>(channel);
    switch (content) {
        case Content::raw:
        case Content::engineering:
            return tags.channels.at(c).name;
        case Content::input_bit:
        case Content::output_bit:
            return tags.points.at(c);
        case Content::input_word:
        case Content::output_word:
        case Content::stop_input:
        case Content::counter:
        case Content::reset:
        case Content::link:
        case Content::status:
        case Content::age:
        case Content::online:
            break;
    }
    return "";
}

MapRow module_row(const UnitMap& unit, const Region& region, int s, int channel) {
    const auto type = module_at_slot(s).type;
    const auto tags = tags_at(unit, s);
    return {region.table,
            static_cast<std::uint16_t>(region.base(s) + channel * region.per_channel),
            unit.unit_id,
            module_name(unit, s),
            channel_name(region.content, type, channel),
            std::string{data_type(region)},
            std::string{units(region.content, tags, channel)},
            std::string{access(region)},
            describe(region.content, type, channel, tags),
            tags.name,
            tag_name(region.content, tags, channel)};
}

MapRow link_row(const UnitMap& unit, const LinkField& field) {
    return {Table::input_registers,
            static_cast<std::uint16_t>(field.address),
            unit.unit_id,
            fmt::format("link {}", unit.link_name),
            "",
            std::string{field.data_type},
            std::string{field.units},
            "read",
            std::string{field.description},
            "",
            ""};
}

std::array<bool, slot_count> configured_slots(const UnitMap& unit) {
    std::array<bool, slot_count> configured{};
    if (unit.kind == UnitKind::id2) configured[0] = true;
    for (const auto module : unit.modules)
        configured[static_cast<std::size_t>(slot(module))] = true;
    return configured;
}

void append_rows(std::vector<MapRow>& rows, const UnitMap& unit, const Region& region,
                 const std::array<bool, slot_count>& configured) {
    if (region.first_slot == no_slot) {
        for (const auto& field : link_fields)
            rows.push_back(link_row(unit, field));
        return;
    }
    for (int s = region.first_slot; s < region.first_slot + region.slots; ++s) {
        if (!configured[static_cast<std::size_t>(s)]) continue;
        for (int c = 0; c < region.channels(); ++c)
            rows.push_back(module_row(unit, region, s, c));
    }
}

constexpr std::array<std::string_view, 12> column_names{
    "table", "PDU address", "Modicon", "unit",        "module",      "channel",
    "type",  "units",       "access",  "description", "module name", "channel name"};

std::array<std::string, 12> cells(const MapRow& row) {
    return {std::string{modbus::to_string(row.table)},
            std::to_string(row.address),
            modicon_number(row.table, row.address),
            std::to_string(row.unit_id),
            row.module,
            row.channel,
            row.data_type,
            row.units,
            row.access,
            row.description,
            row.module_name,
            row.channel_name};
}

std::string markdown_cell(std::string_view text) {
    std::string out;
    for (const char c : text) {
        if (c == '|') out += '\\';
        out += c;
    }
    return out;
}

std::string csv_field(std::string_view text) {
    if (text.find_first_of(",\"\r\n") == std::string_view::npos) return std::string{text};
    std::string out = "\"";
    for (const char c : text) {
        if (c == '"') out += '"';
        out += c;
    }
    return out + '"';
}

template <class Cells, class Escape>
std::string join_line(const Cells& row, std::string_view separator, Escape escape) {
    std::string line;
    for (std::size_t i = 0; i < row.size(); ++i) {
        if (i != 0) line += separator;
        line += escape(row[i]);
    }
    return line;
}

}  // namespace

// --- 32-bit values --------------------------------------------------------------------------

std::array<std::uint16_t, 2> words(std::uint32_t value, WordOrder order) {
    const auto high = static_cast<std::uint16_t>(value >> 16);
    const auto low = static_cast<std::uint16_t>(value & 0xFFFF);
    if (order == WordOrder::big) return {high, low};
    return {low, high};
}

std::array<std::uint16_t, 2> words(float value, WordOrder order) {
    return words(std::bit_cast<std::uint32_t>(value), order);
}

float engineering_float(ModuleType type, std::uint16_t raw) {
    return static_cast<float>(engineering_value(type, raw));
}

// --- Requests -------------------------------------------------------------------------------

std::uint16_t merged(std::uint16_t desired, const OutputChange& change) {
    return static_cast<std::uint16_t>((desired & ~change.mask) | (change.value & change.mask));
}

// FC 23's read part as the FC 03 it amounts to.
Request read_part(std::uint16_t address, std::uint16_t quantity) {
    Request read;
    read.function = modbus::Function::read_holding_registers;
    read.table = Table::holding_registers;
    read.address = address;
    read.quantity = quantity;
    read.well_formed = true;
    return read;
}

Plan plan(const UnitState& unit, const Policy& policy, std::span<const std::uint8_t> pdu) {
    const auto request = modbus::parse_request(pdu);
    if (!request) return request.error();
    if (request->write && policy.read_only) return Exception::illegal_function;
    if (const auto wrong = modbus::check_limits(*request)) return *wrong;
    const auto start = locate_range(unit.kind, *request);
    if (!start) return Exception::illegal_data_address;
    const bool read_write = request->function == modbus::Function::read_write_multiple_registers;
    if (read_write &&
        !locate_range(unit.kind, read_part(request->read_address, request->read_quantity)))
        return Exception::illegal_data_address;
    if (!request->write) return plan_read(unit, policy, *request, *start);
    auto write = plan_write(unit, *request, locate_each(unit.kind, *request));
    auto* changes = std::get_if<WritePlan>(&write);
    if (changes == nullptr || !read_write) return write;
    changes->read_address = request->read_address;
    changes->read_quantity = request->read_quantity;
    // A read part that would answer 0B whatever the write does answers it now, before anything
    // is sent: a client must never be told 0B for outputs that were set. The modules written are
    // judged as they will be once their commands are confirmed.
    auto written = unit;
    for (const auto& change : changes->changes)
        written.status[static_cast<std::size_t>(slot(change.module))] = ModuleStatus::online;
    const auto read = read_back(written, policy, changes->read_address, changes->read_quantity);
    if (const auto* stale_read = std::get_if<Exception>(&read)) return *stale_read;
    return write;
}

Plan read_back(const UnitState& unit, const Policy& policy, std::uint16_t address,
               std::uint16_t quantity) {
    const auto read = read_part(address, quantity);
    const auto start = locate_range(unit.kind, read);
    if (!start) return Exception::illegal_data_address;  // plan() ruled this out
    return plan_read(unit, policy, read, *start);
}

// --- The tables -----------------------------------------------------------------------------

void store_reading(const Tables& tables, ModuleAddress module, const Reading& reading,
                   WordOrder order, std::span<const std::optional<PointValue>> values) {
    // Analog modules' points are raw0…rawN-1, then value0…valueN-1.
    const auto channels = values.size() / 2;
    for_each_channel(module, [&](const Region& region, int address, int c) {
        switch (region.content) {
            case Content::input_bit:
                put(tables, region.table, address, bit(reading.raw[0], c));
                break;
            case Content::input_word:
            case Content::raw:
                put(tables, region.table, address, channel_raw(reading, c));
                break;
            case Content::engineering:
                if (const auto& value = values[channels + static_cast<std::size_t>(c)])
                    put_words(tables, address, words(std::get<float>(*value), order));
                break;
            case Content::output_bit:
            case Content::output_word:
            case Content::stop_input:
            case Content::counter:
            case Content::reset:
            case Content::link:
            case Content::status:
            case Content::age:
            case Content::online:
                break;  // not a reading's: outputs, the ID-2, diagnostics
        }
    });
}

void store_output(const Tables& tables, ModuleAddress module, std::uint16_t value) {
    for_each_channel(module, [&](const Region& region, int address, int c) {
        if (region.content == Content::output_bit)
            put(tables, region.table, address, bit(value, c));
        else if (region.content == Content::output_word)
            put(tables, region.table, address, value);
    });
}

void store_id2(const Tables& tables, id2::Command command, std::uint16_t value) {
    const auto content = command == id2::Command::stop_input ? Content::stop_input
                         : command == id2::Command::count    ? Content::counter
                                                             : Content::reset;
    if (content == Content::reset) return;  // a command, nothing to show
    for (const auto& region : id2_data)
        if (region.content == content) put(tables, region.table, region.first, value);
}

void store_diagnostics(const Tables& tables, const Diagnostics& diagnostics, WordOrder order) {
    const auto link = Table::input_registers;
    put(tables, link, link_state_address, static_cast<std::uint16_t>(diagnostics.link_state));
    put(tables, link, cycle_time_address, tenths_of_ms(diagnostics.last_cycle));
    put_words(tables, cycles_address, counter_words(diagnostics.cycles, order));
    put_words(tables, ok_address, counter_words(diagnostics.transactions_ok, order));
    put_words(tables, failed_address, counter_words(diagnostics.transactions_failed, order));
    put_words(tables, opens_address, counter_words(diagnostics.opens, order));
    for (int s = 0; s < slot_count; ++s) {
        const auto i = static_cast<std::size_t>(s);
        const auto status = diagnostics.status[i];
        const bool configured = status != ModuleStatus::not_configured;
        put(tables, link, status_address + s, static_cast<std::uint16_t>(status));
        put(tables, link, age_address + s,
            configured ? saturate16(diagnostics.age_ms[i]) : std::uint16_t{0xFFFF});
        put(tables, Table::discrete_inputs, online_address + s,
            status == ModuleStatus::online ? 1 : 0);
    }
}

bool is_write(std::uint8_t function) {
    switch (static_cast<modbus::Function>(function)) {
        case modbus::Function::write_single_coil:
        case modbus::Function::write_single_register:
        case modbus::Function::write_multiple_coils:
        case modbus::Function::write_multiple_registers:
        case modbus::Function::read_write_multiple_registers:
            return true;
        case modbus::Function::read_coils:
        case modbus::Function::read_discrete_inputs:
        case modbus::Function::read_holding_registers:
        case modbus::Function::read_input_registers:
            return false;
    }
    return false;  // any other code, device identification included
}

void count_response(Traffic& traffic, std::uint8_t function,
                    std::span<const std::uint8_t> response) {
    ++traffic.requests;
    const bool exception = !response.empty() && (response[0] & 0x80U) != 0;
    if (!exception) {
        if (is_write(function)) ++traffic.writes_confirmed;
        return;
    }
    ++traffic.exceptions;
    const auto code = response.size() > 1 ? response[1] : std::uint8_t{0};
    if (is_write(function) &&
        (code == static_cast<std::uint8_t>(Exception::server_device_failure) ||
         code == static_cast<std::uint8_t>(Exception::gateway_target_failed)))
        ++traffic.writes_failed;
}

void store_front(const Tables& tables, const Front& front, WordOrder order) {
    const auto& traffic = front.traffic;
    put_words(tables, requests_address, counter_words(traffic.requests, order));
    put_words(tables, exceptions_address, counter_words(traffic.exceptions, order));
    put_words(tables, writes_confirmed_address, counter_words(traffic.writes_confirmed, order));
    put_words(tables, writes_failed_address, counter_words(traffic.writes_failed, order));
    put(tables, Table::input_registers, connections_address, saturate16(front.connections));
    put(tables, Table::input_registers, since_previous_address,
        saturate16(static_cast<std::uint64_t>(
            std::chrono::duration_cast<std::chrono::seconds>(front.since_previous_request)
                .count())));
    put(tables, Table::input_registers, comm_loss_address, front.comm_loss ? 1 : 0);
}

// --- The printable map ----------------------------------------------------------------------

std::string modicon_number(modbus::Table table, std::uint16_t address) {
    const char prefix = table == Table::coils             ? '0'
                        : table == Table::discrete_inputs ? '1'
                        : table == Table::input_registers ? '3'
                                                          : '4';
    return fmt::format("{}{:05}", prefix, address + 1);
}

std::vector<MapRow> map_rows(const UnitMap& unit) {
    const auto configured = configured_slots(unit);
    std::vector<MapRow> rows;
    for (const auto& region : regions(unit.kind))
        append_rows(rows, unit, region, configured);
    std::stable_sort(rows.begin(), rows.end(), [](const MapRow& a, const MapRow& b) {
        return std::pair{a.table, a.address} < std::pair{b.table, b.address};
    });
    return rows;
}

std::string format_markdown(std::span<const MapRow> rows) {
    const auto plain = [](std::string_view text) { return std::string{text}; };
    std::string out = "| " + join_line(column_names, " | ", plain) + " |\n";
    out += "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& row : rows)
        out += "| " + join_line(cells(row), " | ", markdown_cell) + " |\n";
    return out;
}

std::string format_csv(std::span<const MapRow> rows) {
    // RFC 4180 ends every record with CRLF.
    std::string out = join_line(column_names, ",", csv_field) + "\r\n";
    for (const auto& row : rows)
        out += join_line(cells(row), ",", csv_field) + "\r\n";
    return out;
}

}  // namespace ioport::gateway
