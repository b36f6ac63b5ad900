// The gateway's Modbus map (shared/spec/gateway.md §2–§4): where data lives, which requests
// are answered how, and the printed map. Addresses and values are taken from the spec, not
// from the implementation's tables.
#include <gtest/gtest.h>

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <initializer_list>
#include <vector>

#include "protocol/gateway_map.hpp"
#include "protocol/points.hpp"

namespace ioport::gateway {
namespace {

// A good reading stored as the daemon stores it: with the module's point values, scaled as
// `tags` say (protocol/points.hpp).
void store_reading(const Tables& tables, ModuleAddress module, const Reading& reading,
                   WordOrder order, const ModuleTags& tags = no_tags) {
    std::vector<std::optional<PointValue>> values;
    point_values(module.type, {reading, {}, {}, {}}, tags, values);
    gateway::store_reading(tables, module, reading, order, values);
}

using modbus::Exception;
using modbus::Table;
using namespace std::chrono_literals;
using Bytes = std::vector<std::uint8_t>;

// A 32-bit value read back from its two registers, as a Modbus client decodes it.
std::uint32_t u32_from_words(std::array<std::uint16_t, 2> value, WordOrder order) {
    const auto [high, low] =
        order == WordOrder::big ? value : std::array<std::uint16_t, 2>{value[1], value[0]};
    return static_cast<std::uint32_t>(high) << 16 | low;
}
float float_from_words(std::array<std::uint16_t, 2> value, WordOrder order) {
    return std::bit_cast<float>(u32_from_words(value, order));
}

constexpr ModuleAddress dim16(std::uint8_t n) {
    return {ModuleType::dim16, n};
}
constexpr ModuleAddress dom16(std::uint8_t n) {
    return {ModuleType::dom16, n};
}
constexpr ModuleAddress acm3p(std::uint8_t n) {
    return {ModuleType::acm3p, n};
}
constexpr ModuleAddress acm3c(std::uint8_t n) {
    return {ModuleType::acm3c, n};
}
constexpr ModuleAddress lim16(std::uint8_t n) {
    return {ModuleType::lim16, n};
}
constexpr ModuleAddress rgbdm(std::uint8_t n) {
    return {ModuleType::rgbdm, n};
}
constexpr ModuleAddress dccim(std::uint8_t n) {
    return {ModuleType::dccim, n};
}
constexpr ModuleAddress dcvim(std::uint8_t n) {
    return {ModuleType::dcvim, n};
}
constexpr ModuleAddress mux8m(std::uint8_t n) {
    return {ModuleType::mux8m, n};
}

// The four tables of one unit, zeroed, as the daemon starts them.
struct Image {
    std::vector<std::uint8_t> coils = std::vector<std::uint8_t>(coil_count);
    std::vector<std::uint8_t> discrete_inputs = std::vector<std::uint8_t>(discrete_input_count);
    std::vector<std::uint16_t> holding_registers =
        std::vector<std::uint16_t>(holding_register_count);
    std::vector<std::uint16_t> input_registers = std::vector<std::uint16_t>(input_register_count);
    Tables tables() { return {coils, discrete_inputs, holding_registers, input_registers}; }
    std::array<std::uint16_t, 2> pair(std::size_t address) const {
        return {input_registers[address], input_registers[address + 1]};
    }
    bool all_zero() const {
        const auto zero = [](auto value) { return value == 0; };
        return std::all_of(coils.begin(), coils.end(), zero) &&
               std::all_of(discrete_inputs.begin(), discrete_inputs.end(), zero) &&
               std::all_of(holding_registers.begin(), holding_registers.end(), zero) &&
               std::all_of(input_registers.begin(), input_registers.end(), zero);
    }
};

constexpr std::uint8_t high(std::uint16_t value) {
    return static_cast<std::uint8_t>(value >> 8);
}
constexpr std::uint8_t low(std::uint16_t value) {
    return static_cast<std::uint8_t>(value & 0xFF);
}

Bytes read_pdu(Table table, std::uint16_t address, std::uint16_t quantity) {
    const auto code = static_cast<std::uint8_t>(static_cast<int>(table) + 1);  // FC 01-04
    return {code, high(address), low(address), high(quantity), low(quantity)};
}
Bytes write_coil(std::uint16_t address, bool on) {
    return {0x05, high(address), low(address), on ? std::uint8_t{0xFF} : std::uint8_t{0}, 0x00};
}
Bytes write_register(std::uint16_t address, std::uint16_t value) {
    return {0x06, high(address), low(address), high(value), low(value)};
}
Bytes write_coils(std::uint16_t address, std::initializer_list<int> bits) {
    const auto quantity = static_cast<std::uint16_t>(bits.size());
    Bytes pdu{0x0F,           high(address), low(address),
              high(quantity), low(quantity), static_cast<std::uint8_t>((quantity + 7) / 8)};
    pdu.resize(pdu.size() + pdu[5]);
    int i = 0;
    for (const int b : bits) {
        if (b != 0) pdu[6 + i / 8] = static_cast<std::uint8_t>(pdu[6 + i / 8] | 1 << (i % 8));
        ++i;
    }
    return pdu;
}
Bytes write_registers(std::uint16_t address, std::initializer_list<std::uint16_t> values) {
    const auto quantity = static_cast<std::uint16_t>(values.size());
    Bytes pdu{0x10,           high(address), low(address),
              high(quantity), low(quantity), static_cast<std::uint8_t>(quantity * 2)};
    for (const auto value : values) {
        pdu.push_back(high(value));
        pdu.push_back(low(value));
    }
    return pdu;
}

void set(UnitState& unit, ModuleAddress module, ModuleStatus status) {
    unit.status[static_cast<std::size_t>(slot(module))] = status;
}

UnitState ioport_unit(std::initializer_list<ModuleAddress> online, bool port_open = true) {
    UnitState unit{UnitKind::ioport, port_open, {}};
    for (const auto module : online)
        set(unit, module, ModuleStatus::online);
    return unit;
}

UnitState id2_unit(ModuleStatus status = ModuleStatus::online, bool port_open = true) {
    UnitState unit{UnitKind::id2, port_open, {}};
    unit.status[0] = status;
    return unit;
}

const Policy strict{false, Stale::exception};
const Policy hold{false, Stale::hold};
const Policy read_only{true, Stale::exception};

Plan ok_read(bool diagnostics = false) {
    return ReadPlan{diagnostics};
}
Plan reset_plan() {
    return WritePlan{{}, true};
}
Plan changes(std::vector<OutputChange> list) {
    return WritePlan{std::move(list), false};
}

// The bits of a float computed with the vendor formula, independently of the code under test.
std::uint32_t vendor_bits(int raw, double full_scale) {
    return std::bit_cast<std::uint32_t>(static_cast<float>(raw / 65535.0 * full_scale));
}

// --- §2.1 the ioport unit, row by row ---------------------------------------------------------

TEST(GatewayStore, Dim16InputsAreDiscreteInputsAndOneInputRegister) {
    Image image;
    store_reading(image.tables(), dim16(2), Reading{{0x8001, 0, 0}, 1}, WordOrder::big);
    EXPECT_EQ(image.input_registers[2], 0x8001);  // n
    EXPECT_EQ(image.discrete_inputs[32], 1);      // n*16 + 0
    for (int k = 1; k < 15; ++k)
        EXPECT_EQ(image.discrete_inputs[static_cast<std::size_t>(32 + k)], 0) << k;
    EXPECT_EQ(image.discrete_inputs[47], 1);  // n*16 + 15
    EXPECT_EQ(image.discrete_inputs[31], 0);
    EXPECT_EQ(image.discrete_inputs[48], 0);

    store_reading(image.tables(), dim16(7), Reading{{0x8000, 0, 0}, 1}, WordOrder::big);
    EXPECT_EQ(image.discrete_inputs[127], 1);
    EXPECT_EQ(image.input_registers[7], 0x8000);
}

TEST(GatewayStore, Lim16InputsFollowDim16) {
    Image image;
    store_reading(image.tables(), lim16(0), Reading{{0x0001, 0, 0}, 1}, WordOrder::big);
    EXPECT_EQ(image.discrete_inputs[128], 1);  // 128 + n*16 + k
    EXPECT_EQ(image.input_registers[8], 1);    // 8 + n
    store_reading(image.tables(), lim16(3), Reading{{0x0004, 0, 0}, 1}, WordOrder::big);
    EXPECT_EQ(image.discrete_inputs[128 + 48 + 2], 1);
    EXPECT_EQ(image.input_registers[11], 4);
    store_reading(image.tables(), lim16(7), Reading{{0x8000, 0, 0}, 1}, WordOrder::big);
    EXPECT_EQ(image.discrete_inputs[255], 1);
    EXPECT_EQ(image.input_registers[15], 0x8000);
    EXPECT_EQ(image.discrete_inputs[127], 0);  // dim16 7 untouched
}

TEST(GatewayStore, Dom16IsOneHoldingRegisterAndSixteenCoils) {
    Image image;
    store_output(image.tables(), dom16(1), 0x8003);
    EXPECT_EQ(image.holding_registers[1], 0x8003);
    EXPECT_EQ(image.coils[16], 1);
    EXPECT_EQ(image.coils[17], 1);
    EXPECT_EQ(image.coils[18], 0);
    EXPECT_EQ(image.coils[31], 1);
    EXPECT_EQ(image.coils[15], 0);
    EXPECT_EQ(image.coils[32], 0);
    // The two views agree after every change, also when bits go back to 0.
    store_output(image.tables(), dom16(1), 0x0002);
    EXPECT_EQ(image.holding_registers[1], 0x0002);
    EXPECT_EQ(image.coils[16], 0);
    EXPECT_EQ(image.coils[17], 1);
    EXPECT_EQ(image.coils[31], 0);

    store_output(image.tables(), dom16(7), 0xFFFF);
    EXPECT_EQ(image.holding_registers[7], 0xFFFF);
    EXPECT_EQ(image.coils[112], 1);
    EXPECT_EQ(image.coils[127], 1);
}

TEST(GatewayStore, RgbdmAndMux8mHoldingRegisters) {
    Image image;
    store_output(image.tables(), rgbdm(0), 1);
    store_output(image.tables(), rgbdm(7), 7);
    store_output(image.tables(), mux8m(0), 0x0305);
    store_output(image.tables(), mux8m(7), 0x0707);
    EXPECT_EQ(image.holding_registers[8], 1);  // 8 + n
    EXPECT_EQ(image.holding_registers[15], 7);
    EXPECT_EQ(image.holding_registers[16], 0x0305);  // 16 + n
    EXPECT_EQ(image.holding_registers[23], 0x0707);
    EXPECT_EQ(std::count(image.coils.begin(), image.coils.end(), 1), 0);
}

TEST(GatewayStore, StoringAnOutputIntoAnInputModuleChangesNothing) {
    Image image;
    store_output(image.tables(), dim16(0), 0xFFFF);
    store_reading(image.tables(), dom16(0), Reading{{0xFFFF, 0, 0}, 1}, WordOrder::big);
    EXPECT_TRUE(image.all_zero());
}

TEST(GatewayStore, Acm3pRawAndPercent) {
    Image image;
    store_reading(image.tables(), acm3p(1), Reading{{13208, 0, 65535}, 3}, WordOrder::big);
    EXPECT_EQ(image.input_registers[19], 13208);  // 16 + n*3 + c
    EXPECT_EQ(image.input_registers[20], 0);
    EXPECT_EQ(image.input_registers[21], 65535);
    // 200 + (n*3 + c)*2: 13208 / 65535 * 100 = 20.15411612…, single precision 0x41A13BA1.
    EXPECT_EQ(vendor_bits(13208, 100), 0x41A13BA1U);
    EXPECT_EQ(image.pair(206), (std::array<std::uint16_t, 2>{0x41A1, 0x3BA1}));
    EXPECT_EQ(image.pair(208), (std::array<std::uint16_t, 2>{0, 0}));
    EXPECT_EQ(image.pair(210), (std::array<std::uint16_t, 2>{0x42C8, 0x0000}));  // 100.0f
    EXPECT_EQ(float_from_words(image.pair(206), WordOrder::big),
              static_cast<float>(13208 / 65535.0 * 100));
}

TEST(GatewayStore, Acm3cRawAndPercentAtTheEndOfTheirRanges) {
    Image image;
    store_reading(image.tables(), acm3c(7), Reading{{1, 2, 3}, 3}, WordOrder::big);
    EXPECT_EQ(image.input_registers[61], 1);  // 40 + 7*3 + 0
    EXPECT_EQ(image.input_registers[62], 2);
    EXPECT_EQ(image.input_registers[63], 3);
    const auto expected = vendor_bits(3, 100);
    EXPECT_EQ(image.pair(294),
              (std::array<std::uint16_t, 2>{static_cast<std::uint16_t>(expected >> 16),
                                            static_cast<std::uint16_t>(expected & 0xFFFF)}));
    EXPECT_EQ(vendor_bits(1, 100), 0x3AC800C8U);
    EXPECT_EQ(image.pair(290), (std::array<std::uint16_t, 2>{0x3AC8, 0x00C8}));
    store_reading(image.tables(), acm3c(0), Reading{{65535, 0, 0}, 3}, WordOrder::big);
    EXPECT_EQ(image.input_registers[40], 65535);
    EXPECT_EQ(image.pair(248), (std::array<std::uint16_t, 2>{0x42C8, 0x0000}));
}

TEST(GatewayStore, DccimAmperesAndDcvimVolts) {
    Image image;
    store_reading(image.tables(), dccim(0), Reading{{32768, 0, 0}, 1}, WordOrder::big);
    store_reading(image.tables(), dccim(7), Reading{{65535, 0, 0}, 1}, WordOrder::big);
    store_reading(image.tables(), dcvim(0), Reading{{12345, 0, 0}, 1}, WordOrder::big);
    store_reading(image.tables(), dcvim(7), Reading{{65535, 0, 0}, 1}, WordOrder::big);
    EXPECT_EQ(image.input_registers[64], 32768);  // 64 + n
    EXPECT_EQ(image.input_registers[71], 65535);
    EXPECT_EQ(image.input_registers[72], 12345);  // 72 + n
    EXPECT_EQ(image.input_registers[79], 65535);
    // 32768 / 65535 * 6 = 3.0000457…; 12345 / 65535 * 32 = 6.0279240…
    EXPECT_EQ(vendor_bits(32768, 6), 0x404000C0U);
    EXPECT_EQ(vendor_bits(12345, 32), 0x40C0E4C1U);
    EXPECT_EQ(image.pair(296), (std::array<std::uint16_t, 2>{0x4040, 0x00C0}));  // 296 + n*2
    EXPECT_EQ(image.pair(310), (std::array<std::uint16_t, 2>{0x40C0, 0x0000}));  // 6.0 A
    EXPECT_EQ(image.pair(312), (std::array<std::uint16_t, 2>{0x40C0, 0xE4C1}));  // 312 + n*2
    EXPECT_EQ(image.pair(326), (std::array<std::uint16_t, 2>{0x4200, 0x0000}));  // 32.0 V
}

TEST(GatewayStore, FloatsInLittleWordOrderPutTheLowWordFirst) {
    Image image;
    store_reading(image.tables(), acm3p(0), Reading{{13208, 1, 65535}, 3}, WordOrder::little);
    EXPECT_EQ(image.pair(200), (std::array<std::uint16_t, 2>{0x3BA1, 0x41A1}));
    EXPECT_EQ(image.pair(202), (std::array<std::uint16_t, 2>{0x00C8, 0x3AC8}));
    EXPECT_EQ(image.pair(204), (std::array<std::uint16_t, 2>{0x0000, 0x42C8}));
    EXPECT_EQ(float_from_words(image.pair(200), WordOrder::little),
              static_cast<float>(13208 / 65535.0 * 100));
    EXPECT_EQ(image.input_registers[16], 13208);  // raw words have no order
}

TEST(GatewayStore, ScaledChannelsCarryTheEngineeringValueAndRawStaysRaw) {
    Image image;
    auto tags = default_tags(acm3p(0));
    tags.channels[0].scale = Scale{0, 100, -20, 150};
    store_reading(image.tables(), acm3p(0), Reading{{13208, 0, 65535}, 3}, WordOrder::big, tags);
    EXPECT_EQ(image.input_registers[16], 13208);
    // -20 + 20.154116…% × 1.7 = 14.262 °C, from the double and rounded once.
    EXPECT_EQ(float_from_words(image.pair(200), WordOrder::big),
              static_cast<float>(-20.0 + 13208 / 65535.0 * 100.0 * 170.0 / 100.0));
    EXPECT_EQ(float_from_words(image.pair(204), WordOrder::big), 100.0F);  // channel 2: %
}

TEST(GatewayValues, EngineeringFloatIsTheVendorFormulaRoundedOnce) {
    EXPECT_EQ(std::bit_cast<std::uint32_t>(engineering_float(ModuleType::acm3p, 13208)),
              0x41A13BA1U);
    EXPECT_EQ(std::bit_cast<std::uint32_t>(engineering_float(ModuleType::acm3c, 1)), 0x3AC800C8U);
    EXPECT_EQ(std::bit_cast<std::uint32_t>(engineering_float(ModuleType::dccim, 32768)),
              0x404000C0U);
    EXPECT_EQ(std::bit_cast<std::uint32_t>(engineering_float(ModuleType::dcvim, 12345)),
              0x40C0E4C1U);
    EXPECT_EQ(engineering_float(ModuleType::dcvim, 0), 0.0F);
    EXPECT_EQ(engineering_float(ModuleType::dcvim, 65535), 32.0F);
}

TEST(GatewayValues, WordsOfThirtyTwoBits) {
    EXPECT_EQ(words(std::uint32_t{0x12345678}, WordOrder::big),
              (std::array<std::uint16_t, 2>{0x1234, 0x5678}));
    EXPECT_EQ(words(std::uint32_t{0x12345678}, WordOrder::little),
              (std::array<std::uint16_t, 2>{0x5678, 0x1234}));
    EXPECT_EQ(u32_from_words({0x1234, 0x5678}, WordOrder::big), 0x12345678U);
    EXPECT_EQ(u32_from_words({0x1234, 0x5678}, WordOrder::little), 0x56781234U);
    EXPECT_EQ(words(1.0F, WordOrder::big), (std::array<std::uint16_t, 2>{0x3F80, 0x0000}));
    EXPECT_EQ(words(-2.5F, WordOrder::little), (std::array<std::uint16_t, 2>{0x0000, 0xC020}));
    for (const auto order : {WordOrder::big, WordOrder::little}) {
        EXPECT_EQ(u32_from_words(words(std::uint32_t{0xDEADBEEF}, order), order), 0xDEADBEEFU);
        EXPECT_EQ(float_from_words(words(20.154116F, order), order), 20.154116F);
    }
}

// --- §2.2 the ID-2 unit -----------------------------------------------------------------------

TEST(GatewayStore, Id2StopInputAndCounter) {
    Image image;
    store_id2(image.tables(), id2::Command::stop_input, 1);
    EXPECT_EQ(image.discrete_inputs[0], 1);
    store_id2(image.tables(), id2::Command::count, 65535);
    EXPECT_EQ(image.input_registers[0], 65535);
    store_id2(image.tables(), id2::Command::count, 42);
    EXPECT_EQ(image.input_registers[0], 42);
    store_id2(image.tables(), id2::Command::stop_input, 0);
    EXPECT_EQ(image.discrete_inputs[0], 0);
    store_id2(image.tables(), id2::Command::reset, 0);
    EXPECT_EQ(image.coils[0], 0);  // coil 0 reads 0
    EXPECT_EQ(image.input_registers[0], 42);
}

// --- §2.3 diagnostics -------------------------------------------------------------------------

Diagnostics sample_diagnostics() {
    Diagnostics d;
    d.link_state = LinkState::some_offline;
    d.last_cycle = 12'345us;
    d.cycles = 0x0001'0002;
    d.transactions_ok = 70'000;
    d.transactions_failed = 3;
    d.opens = 1;
    d.status.fill(ModuleStatus::not_configured);
    d.age_ms.fill(12);  // ignored where not configured
    d.status[0] = ModuleStatus::online;
    d.age_ms[0] = 40;
    d.status[8] = ModuleStatus::no_answer;
    d.age_ms[8] = 70'000;
    d.status[16] = ModuleStatus::bad_answer;
    d.age_ms[16] = 65'535;
    d.status[71] = ModuleStatus::not_polled;
    d.age_ms[71] = 65'534;
    return d;
}

TEST(GatewayDiagnostics, LinkRegisters) {
    Image image;
    store_diagnostics(image.tables(), sample_diagnostics(), WordOrder::big);
    EXPECT_EQ(image.input_registers[1000], 2);    // some module not online
    EXPECT_EQ(image.input_registers[1001], 123);  // 12.345 ms in 0.1 ms
    EXPECT_EQ(image.pair(1002), (std::array<std::uint16_t, 2>{0x0001, 0x0002}));
    EXPECT_EQ(image.pair(1004), (std::array<std::uint16_t, 2>{0x0001, 0x1170}));  // 70000
    EXPECT_EQ(image.pair(1006), (std::array<std::uint16_t, 2>{0, 3}));
    EXPECT_EQ(image.pair(1008), (std::array<std::uint16_t, 2>{0, 1}));

    store_diagnostics(image.tables(), sample_diagnostics(), WordOrder::little);
    EXPECT_EQ(image.pair(1002), (std::array<std::uint16_t, 2>{0x0002, 0x0001}));
    EXPECT_EQ(u32_from_words(image.pair(1004), WordOrder::little), 70'000U);
}

TEST(GatewayDiagnostics, LinkStates) {
    Image image;
    auto d = sample_diagnostics();
    for (const auto& [state, value] :
         {std::pair{LinkState::port_not_open, 0}, std::pair{LinkState::all_online, 1},
          std::pair{LinkState::some_offline, 2}}) {
        d.link_state = state;
        store_diagnostics(image.tables(), d, WordOrder::big);
        EXPECT_EQ(image.input_registers[1000], value);
    }
}

TEST(GatewayDiagnostics, CycleTimeSaturatesAt65535) {
    Image image;
    auto d = sample_diagnostics();
    d.last_cycle = 6'553'500us;
    store_diagnostics(image.tables(), d, WordOrder::big);
    EXPECT_EQ(image.input_registers[1001], 65535);
    d.last_cycle = 6'553'600us;
    store_diagnostics(image.tables(), d, WordOrder::big);
    EXPECT_EQ(image.input_registers[1001], 65535);
    d.last_cycle = 1h;
    store_diagnostics(image.tables(), d, WordOrder::big);
    EXPECT_EQ(image.input_registers[1001], 65535);
    d.last_cycle = 99us;
    store_diagnostics(image.tables(), d, WordOrder::big);
    EXPECT_EQ(image.input_registers[1001], 0);
}

TEST(GatewayDiagnostics, CountersAreModulo2To32) {
    Image image;
    auto d = sample_diagnostics();
    d.cycles = 0x1'0000'0005;
    d.transactions_ok = 0xFFFF'FFFF;
    d.transactions_failed = 0x2'0000'0000;
    d.opens = 0xABCD'1234'5678;
    store_diagnostics(image.tables(), d, WordOrder::big);
    EXPECT_EQ(image.pair(1002), (std::array<std::uint16_t, 2>{0, 5}));
    EXPECT_EQ(image.pair(1004), (std::array<std::uint16_t, 2>{0xFFFF, 0xFFFF}));
    EXPECT_EQ(image.pair(1006), (std::array<std::uint16_t, 2>{0, 0}));
    EXPECT_EQ(image.pair(1008), (std::array<std::uint16_t, 2>{0x1234, 0x5678}));
}

// §5.1: a request is counted when its response is sent; writes are FC 05, 06, 15, 16 and 23.
TEST(GatewayTraffic, ResponsesAreCountedByKind) {
    Traffic traffic;
    const Bytes read_ok{0x03, 0x02, 0x00, 0x01};
    count_response(traffic, 0x03, read_ok);
    count_response(traffic, 0x06, Bytes{0x06, 0x00, 0x00, 0x12, 0x34});
    count_response(traffic, 0x17, Bytes{0x17, 0x02, 0x00, 0x01});
    count_response(traffic, 0x10, Bytes{0x90, 0x04});  // error ack
    count_response(traffic, 0x05, Bytes{0x85, 0x0B});  // no answer, or a closed port
    count_response(traffic, 0x0F, Bytes{0x8F, 0x03});  // refused before it was sent
    count_response(traffic, 0x04, Bytes{0x84, 0x0B});  // a stale read
    count_response(traffic, 0x2B, Bytes{0xAB, 0x02});  // identification is not a write
    EXPECT_EQ(traffic.requests, 8u);
    EXPECT_EQ(traffic.exceptions, 5u);
    EXPECT_EQ(traffic.writes_confirmed, 2u);
    EXPECT_EQ(traffic.writes_failed, 2u);
}

TEST(GatewayTraffic, Registers1010To1020) {
    Image image;
    Front front;
    front.traffic = {0x1'0000'0007, 3, 0xFFFF'FFFF, 0x12'3456};
    front.connections = 70000;
    front.since_previous_request = 2500ms;
    front.comm_loss = true;
    store_front(image.tables(), front, WordOrder::big);
    EXPECT_EQ(image.pair(1010), (std::array<std::uint16_t, 2>{0, 7}));  // modulo 2^32
    EXPECT_EQ(image.pair(1012), (std::array<std::uint16_t, 2>{0, 3}));
    EXPECT_EQ(image.pair(1014), (std::array<std::uint16_t, 2>{0xFFFF, 0xFFFF}));
    EXPECT_EQ(image.pair(1016), (std::array<std::uint16_t, 2>{0x12, 0x3456}));
    EXPECT_EQ(image.input_registers[1018], 65535);  // saturates
    EXPECT_EQ(image.input_registers[1019], 2);      // whole seconds
    EXPECT_EQ(image.input_registers[1020], 1);
    front.since_previous_request = 100h;
    front.comm_loss = false;
    store_front(image.tables(), front, WordOrder::little);
    EXPECT_EQ(image.pair(1016), (std::array<std::uint16_t, 2>{0x3456, 0x12}));
    EXPECT_EQ(image.input_registers[1019], 65535);
    EXPECT_EQ(image.input_registers[1020], 0);
}

TEST(GatewayDiagnostics, ModuleStatusAgeAndOnline) {
    Image image;
    store_diagnostics(image.tables(), sample_diagnostics(), WordOrder::big);
    EXPECT_EQ(image.input_registers[1100], 1);  // slot 0 online
    EXPECT_EQ(image.input_registers[1108], 2);  // dom16 0, no answer
    EXPECT_EQ(image.input_registers[1116], 3);  // acm3p 0, bad answer
    EXPECT_EQ(image.input_registers[1171], 4);  // mux8m 7, not polled yet
    EXPECT_EQ(image.input_registers[1101], 0);  // not configured
    EXPECT_EQ(image.input_registers[1200], 40);
    EXPECT_EQ(image.input_registers[1208], 65535);  // 70000 ms saturates
    EXPECT_EQ(image.input_registers[1216], 65535);
    EXPECT_EQ(image.input_registers[1271], 65534);
    EXPECT_EQ(image.input_registers[1201], 65535);  // not configured: 65535, not 12
    EXPECT_EQ(image.discrete_inputs[1000], 1);
    EXPECT_EQ(image.discrete_inputs[1008], 0);
    EXPECT_EQ(image.discrete_inputs[1016], 0);
    EXPECT_EQ(image.discrete_inputs[1071], 0);
    EXPECT_EQ(image.discrete_inputs[1001], 0);

    auto d = sample_diagnostics();
    d.status[8] = ModuleStatus::online;
    store_diagnostics(image.tables(), d, WordOrder::big);
    EXPECT_EQ(image.discrete_inputs[1008], 1);
    d.status[0] = ModuleStatus::no_answer;
    store_diagnostics(image.tables(), d, WordOrder::big);
    EXPECT_EQ(image.discrete_inputs[1000], 0);  // cleared, not only set
}

TEST(GatewayDiagnostics, DataAddressesAreLeftAlone) {
    Image image;
    store_diagnostics(image.tables(), sample_diagnostics(), WordOrder::big);
    for (std::size_t a = 0; a < 1000; ++a) {
        EXPECT_EQ(image.input_registers[a], 0) << a;
        EXPECT_EQ(image.discrete_inputs[a], 0) << a;
    }
}

// --- Reads ------------------------------------------------------------------------------------

TEST(GatewayPlan, ReadsOfOnlineModules) {
    const auto unit = ioport_unit({dim16(0), dom16(0), acm3p(7)});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::discrete_inputs, 0, 16)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::coils, 0, 16)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::holding_registers, 0, 1)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 37, 3)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 242, 6)), ok_read());
}

TEST(GatewayPlan, UnconfiguredModulesReadWithoutException) {
    const auto unit = ioport_unit({}, false);
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 0, 80)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::discrete_inputs, 0, 256)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::coils, 0, 128)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::holding_registers, 0, 24)), ok_read());
}

TEST(GatewayPlan, StaleModulesAnswer0BWithStaleException) {
    for (const auto status :
         {ModuleStatus::no_answer, ModuleStatus::bad_answer, ModuleStatus::not_polled}) {
        auto unit = ioport_unit({dim16(0), dccim(1)});
        set(unit, dccim(1), status);
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 65, 1)),
                  Plan{Exception::gateway_target_failed});
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 298, 2)),
                  Plan{Exception::gateway_target_failed});
        // A range that only touches the stale module in its last address.
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 0, 66)),
                  Plan{Exception::gateway_target_failed});
        // The neighbours are fine.
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 0, 65)), ok_read());
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 66, 1)), ok_read());
        EXPECT_EQ(plan(unit, hold, read_pdu(Table::input_registers, 65, 1)), ok_read());
        EXPECT_EQ(plan(unit, hold, read_pdu(Table::input_registers, 296, 4)), ok_read());
    }
}

TEST(GatewayPlan, StaleOutputsToo) {
    auto unit = ioport_unit({});
    set(unit, dom16(2), ModuleStatus::no_answer);
    set(unit, rgbdm(0), ModuleStatus::not_polled);
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::coils, 47, 1)),
              Plan{Exception::gateway_target_failed});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::coils, 48, 1)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::holding_registers, 2, 1)),
              Plan{Exception::gateway_target_failed});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::holding_registers, 8, 1)),
              Plan{Exception::gateway_target_failed});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::holding_registers, 9, 15)), ok_read());
    EXPECT_EQ(plan(unit, hold, read_pdu(Table::holding_registers, 0, 24)), ok_read());
}

TEST(GatewayPlan, DiagnosticsNeverAnswer0B) {
    auto unit = ioport_unit({}, false);
    unit.status.fill(ModuleStatus::no_answer);
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 1000, 10)), ok_read(true));
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 1100, 72)), ok_read(true));
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 1200, 72)), ok_read(true));
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::discrete_inputs, 1000, 72)), ok_read(true));
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 0, 1)),
              Plan{Exception::gateway_target_failed});
}

// --- Blocks -----------------------------------------------------------------------------------

struct Block {
    Table table;
    std::uint16_t first;
    std::uint16_t last;
};

// gateway.md §4, as written there.
constexpr std::array ioport_blocks{
    Block{Table::input_registers, 0, 79},      Block{Table::input_registers, 200, 327},
    Block{Table::input_registers, 1000, 1020}, Block{Table::input_registers, 1100, 1171},
    Block{Table::input_registers, 1200, 1271}, Block{Table::discrete_inputs, 0, 255},
    Block{Table::discrete_inputs, 1000, 1071}, Block{Table::coils, 0, 127},
    Block{Table::holding_registers, 0, 23},
};
constexpr std::array id2_blocks{
    Block{Table::discrete_inputs, 0, 0},
    Block{Table::input_registers, 0, 0},
    Block{Table::coils, 0, 0},
    Block{Table::input_registers, 1000, 1020},
    Block{Table::input_registers, 1100, 1171},
    Block{Table::input_registers, 1200, 1271},
    Block{Table::discrete_inputs, 1000, 1071},
};

void expect_block_edges(const UnitState& unit, const Block& block) {
    const auto where =
        fmt::format("{} {}-{}", modbus::to_string(block.table), block.first, block.last);
    const bool diagnostics = block.first >= 1000;
    const auto span = static_cast<std::uint16_t>(block.last - block.first + 1);
    const auto whole = std::min<std::uint16_t>(span, 125);
    EXPECT_EQ(plan(unit, hold, read_pdu(block.table, block.first, whole)), ok_read(diagnostics))
        << where;
    EXPECT_EQ(plan(unit, hold, read_pdu(block.table, block.last, 1)), ok_read(diagnostics))
        << where;
    EXPECT_EQ(
        plan(unit, hold, read_pdu(block.table, static_cast<std::uint16_t>(block.last + 1), 1)),
        Plan{Exception::illegal_data_address})
        << where;
    EXPECT_EQ(plan(unit, hold, read_pdu(block.table, block.last, 2)),
              Plan{Exception::illegal_data_address})
        << where;
    if (block.first > 0) {
        EXPECT_EQ(
            plan(unit, hold, read_pdu(block.table, static_cast<std::uint16_t>(block.first - 1), 2)),
            Plan{Exception::illegal_data_address})
            << where;
    }
}

TEST(GatewayBlocks, IoportBlockEdges) {
    const auto unit = ioport_unit({}, true);
    for (const auto& block : ioport_blocks)
        expect_block_edges(unit, block);
}

TEST(GatewayBlocks, Id2BlockEdges) {
    const auto unit = id2_unit();
    for (const auto& block : id2_blocks)
        expect_block_edges(unit, block);
}

TEST(GatewayBlocks, EveryAddressOutsideTheBlocksAnswers02) {
    const auto check = [](UnitKind kind, std::span<const Block> blocks) {
        UnitState unit{kind, true, {}};
        for (const auto table : {Table::coils, Table::discrete_inputs, Table::holding_registers,
                                 Table::input_registers}) {
            for (std::uint16_t a = 0; a < 1400; ++a) {
                const bool inside = std::any_of(blocks.begin(), blocks.end(), [&](const Block& b) {
                    return b.table == table && a >= b.first && a <= b.last;
                });
                const auto answer = plan(unit, hold, read_pdu(table, a, 1));
                EXPECT_EQ(std::holds_alternative<ReadPlan>(answer), inside)
                    << modbus::to_string(table) << " " << a;
            }
        }
    };
    check(UnitKind::ioport, ioport_blocks);
    check(UnitKind::id2, id2_blocks);
}

TEST(GatewayBlocks, RegionsOfOneBlockReadTogether) {
    const auto unit = ioport_unit({}, true);
    // dim16, lim16, acm3p, acm3c, dccim and dcvim words in one request.
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 0, 80)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 240, 80)), ok_read());
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::discrete_inputs, 120, 16)), ok_read());
}

TEST(GatewayBlocks, RangesSpanningTwoBlocksAnswer02) {
    const auto unit = ioport_unit({}, true);
    EXPECT_EQ(plan(unit, hold, read_pdu(Table::input_registers, 79, 122)),
              Plan{Exception::illegal_data_address});  // 79..200
    EXPECT_EQ(plan(unit, hold, read_pdu(Table::input_registers, 1000, 101)),
              Plan{Exception::illegal_data_address});  // 1000..1100
    EXPECT_EQ(plan(unit, hold, read_pdu(Table::input_registers, 1171, 30)),
              Plan{Exception::illegal_data_address});  // 1171..1200
    EXPECT_EQ(plan(unit, hold, read_pdu(Table::discrete_inputs, 0, 2000)),
              Plan{Exception::illegal_data_address});  // 0..1999 over 255 and 1000
    EXPECT_EQ(plan(unit, hold, read_pdu(Table::input_registers, 0xFFFF, 2)),
              Plan{Exception::illegal_data_address});  // past the 16-bit address space
}

// --- Writes -----------------------------------------------------------------------------------

TEST(GatewayPlan, WriteSingleCoilIsOneBitOfOneDom16) {
    const auto unit = ioport_unit({dom16(1)});
    EXPECT_EQ(plan(unit, strict, write_coil(17, true)), changes({{dom16(1), 0x0002, 0x0002}}));
    EXPECT_EQ(plan(unit, strict, write_coil(17, false)), changes({{dom16(1), 0x0002, 0x0000}}));
    EXPECT_EQ(plan(unit, strict, write_coil(31, true)), changes({{dom16(1), 0x8000, 0x8000}}));
}

TEST(GatewayPlan, WriteCoilsAcrossTwoDom16SendsOneChangePerModule) {
    const auto unit = ioport_unit({dom16(0), dom16(1)});
    // Coils 12-19: dom16 0 outputs 12-15, dom16 1 outputs 0-3.
    EXPECT_EQ(plan(unit, strict, write_coils(12, {1, 0, 1, 0, 0, 1, 0, 1})),
              changes({{dom16(0), 0xF000, 0x5000}, {dom16(1), 0x000F, 0x000A}}));
    // All 32 coils of both: each module's mask is whole.
    EXPECT_EQ(plan(unit, strict, write_coils(0, {1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1,
                                                 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1})),
              changes({{dom16(0), 0xFFFF, 0x800F}, {dom16(1), 0xFFFF, 0x8000}}));
}

// The scheduler merges a change into the module's desired state when it sends the command.
TEST(GatewayPlan, AChangeReplacesTheBitsOfItsMaskOnly) {
    const ModuleAddress dom16{ModuleType::dom16, 0};
    EXPECT_EQ(merged(0x00FF, {dom16, 0x0010, 0x0000}), 0x00EF);  // coil 4 off
    EXPECT_EQ(merged(0x00FF, {dom16, 0x0100, 0x0100}), 0x01FF);  // coil 8 on
    EXPECT_EQ(merged(0x00FF, {dom16, 0xFF00, 0xAB00}), 0xABFF);  // coils 8-15
    EXPECT_EQ(merged(0x1234, {dom16, 0xFFFF, 0x0007}), 0x0007);  // the whole register
    EXPECT_EQ(merged(0x1234, {dom16, 0x0000, 0xFFFF}), 0x1234);  // nothing
}

TEST(GatewayPlan, WriteRegistersToEachOutputType) {
    const auto unit = ioport_unit({dom16(3), dom16(7), rgbdm(0), rgbdm(1), mux8m(0)});
    EXPECT_EQ(plan(unit, strict, write_register(3, 0xBEEF)), changes({{dom16(3), 0xFFFF, 0xBEEF}}));
    EXPECT_EQ(plan(unit, strict, write_registers(7, {0x0001, 6, 7})),
              changes({{dom16(7), 0xFFFF, 0x0001}, {rgbdm(0), 0xFFFF, 6}, {rgbdm(1), 0xFFFF, 7}}));
    EXPECT_EQ(plan(unit, strict, write_register(16, 0x0707)),
              changes({{mux8m(0), 0xFFFF, 0x0707}}));
    EXPECT_EQ(plan(unit, strict, write_register(16, 0x0003)),
              changes({{mux8m(0), 0xFFFF, 0x0003}}));
}

// §5.2 FC 23: planned as its write, carrying the read part; both ranges in a holding-register
// block; the precedence of §4 for the write.
Bytes read_write(std::uint16_t read_address, std::uint16_t read_quantity,
                 std::uint16_t write_address, std::initializer_list<std::uint16_t> values) {
    auto pdu = write_registers(write_address, values);
    pdu[0] = 0x17;
    pdu.insert(pdu.begin() + 1,
               {high(read_address), low(read_address), high(read_quantity), low(read_quantity)});
    return pdu;
}

TEST(GatewayPlan, ReadWriteMultipleRegisters) {
    const auto unit = ioport_unit({dom16(0), dom16(1), rgbdm(0)});
    WritePlan expected{{{dom16(1), 0xFFFF, 0x1234}}, false, 0, 9};
    EXPECT_EQ(plan(unit, strict, read_write(0, 9, 1, {0x1234})), Plan{expected});
    // Either range outside the block of holding registers 0-23: 02, before anything is sent.
    EXPECT_EQ(plan(unit, strict, read_write(20, 5, 1, {1})), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, read_write(0, 1, 23, {1, 1})),
              Plan{Exception::illegal_data_address});
    // The write's own checks: an unconfigured module 02, a bad colour 03, read_only 01, a closed
    // port 0B; an ID-2 has no holding registers.
    EXPECT_EQ(plan(unit, strict, read_write(0, 1, 2, {1})), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, read_write(0, 1, 8, {9})), Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, read_only, read_write(0, 1, 1, {1})), Plan{Exception::illegal_function});
    EXPECT_EQ(plan(ioport_unit({dom16(1)}, false), strict, read_write(0, 1, 1, {1})),
              Plan{Exception::gateway_target_failed});
    EXPECT_EQ(plan(id2_unit(), strict, read_write(0, 1, 0, {1})),
              Plan{Exception::illegal_data_address});
    // A read part that touches a module the write does not reach and that is not online answers
    // 0B at once, before anything is sent: never 0B for outputs that were set. A module the
    // write reaches is judged as it will be once confirmed.
    auto offline_rgbdm = unit;
    set(offline_rgbdm, rgbdm(0), ModuleStatus::no_answer);
    EXPECT_EQ(plan(offline_rgbdm, strict, read_write(0, 9, 1, {7})),
              Plan{Exception::gateway_target_failed});
    const WritePlan held{{{dom16(1), 0xFFFF, 7}}, false, 0, 9};
    EXPECT_EQ(plan(offline_rgbdm, hold, read_write(0, 9, 1, {7})), Plan{held});
    const WritePlan reached{{{rgbdm(0), 0xFFFF, 2}}, false, 8, 1};
    EXPECT_EQ(plan(offline_rgbdm, strict, read_write(8, 1, 8, {2})), Plan{reached});
    // The read part, once the write is done: as FC 03 of its range would be then.
    EXPECT_EQ(read_back(unit, strict, 0, 9), ok_read());
    auto offline = unit;
    set(offline, dom16(0), ModuleStatus::no_answer);
    EXPECT_EQ(read_back(offline, strict, 0, 2), Plan{Exception::gateway_target_failed});
    EXPECT_EQ(read_back(offline, hold, 0, 2), ok_read());
    EXPECT_EQ(read_back(offline, strict, 1, 1), ok_read());
}

TEST(GatewayPlan, BadOutputValuesAnswer03) {
    const auto unit = ioport_unit({rgbdm(0), rgbdm(1), mux8m(0)});
    EXPECT_EQ(plan(unit, strict, write_register(8, 8)), Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, write_register(8, 0xFFFF)), Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, write_registers(8, {1, 8})), Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, write_register(16, 0x0800)), Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, write_register(16, 0x0008)), Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, write_register(16, 0x0700)),
              changes({{mux8m(0), 0xFFFF, 0x0700}}));
}

TEST(GatewayPlan, WritesToUnconfiguredModulesAnswer02) {
    const auto unit = ioport_unit({dom16(0), rgbdm(0)});
    EXPECT_EQ(plan(unit, strict, write_coil(16, true)), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_coils(14, {1, 1, 1})),
              Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_register(1, 0)), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_registers(8, {1, 1})),
              Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_register(16, 0)), Plan{Exception::illegal_data_address});
}

TEST(GatewayPlan, WritesToAClosedPortAnswer0B) {
    const auto unit = ioport_unit({dom16(0)}, false);
    EXPECT_EQ(plan(unit, strict, write_coil(0, true)), Plan{Exception::gateway_target_failed});
    EXPECT_EQ(plan(unit, hold, write_register(0, 1)), Plan{Exception::gateway_target_failed});
}

TEST(GatewayPlan, WritesToAnOfflineModuleOnAnOpenPortAreSent) {
    auto unit = ioport_unit({});
    set(unit, dom16(0), ModuleStatus::no_answer);
    EXPECT_EQ(plan(unit, strict, write_register(0, 5)), changes({{dom16(0), 0xFFFF, 5}}));
}

TEST(GatewayPlan, WritesToInputTablesAreImpossible) {
    // FC05/06/15/16 only reach coils and holding registers; addresses past them answer 02.
    const auto unit = ioport_unit({dom16(7), mux8m(7)});
    EXPECT_EQ(plan(unit, strict, write_coil(128, true)), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_register(24, 0)), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_registers(23, {0, 0})),
              Plan{Exception::illegal_data_address});
}

// --- Exception precedence, one step at a time (gateway.md §4) ---------------------------------
// Each request breaks two rules and must answer the earlier one.

TEST(GatewayPrecedence, UnsupportedFunctionBeforeReadOnly) {
    const auto unit = ioport_unit({dom16(0)});
    EXPECT_EQ(plan(unit, read_only, Bytes{0x16, 0x00, 0x00, 0xFF, 0xFF, 0x00, 0x00}),
              Plan{Exception::illegal_function});  // mask write register
    EXPECT_EQ(plan(unit, strict, Bytes{}), Plan{Exception::illegal_function});
}

TEST(GatewayPrecedence, ReadOnlyBeforeLimits) {
    const auto unit = ioport_unit({dom16(0)});
    EXPECT_EQ(plan(unit, read_only, write_coil(0, true)), Plan{Exception::illegal_function});
    EXPECT_EQ(plan(unit, read_only, Bytes{0x05, 0x00, 0x00, 0x12, 0x34}),
              Plan{Exception::illegal_function});  // bad FC05 value too
    EXPECT_EQ(plan(unit, read_only, Bytes{0x10, 0x00, 0x00, 0x00, 0x00, 0x00}),
              Plan{Exception::illegal_function});  // quantity 0 too
    EXPECT_EQ(plan(unit, read_only, Bytes{0x06, 0x00}),
              Plan{Exception::illegal_function});  // mis-sized too
    // Reads are still answered.
    EXPECT_EQ(plan(unit, read_only, read_pdu(Table::holding_registers, 0, 1)), ok_read());
}

TEST(GatewayPrecedence, LimitsBeforeAddress) {
    const auto unit = ioport_unit({dom16(0)});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 5000, 126)),
              Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::coils, 0, 2001)),
              Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::coils, 0, 0)),
              Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, Bytes{0x05, 0x10, 0x00, 0x00, 0x01}),
              Plan{Exception::illegal_data_value});  // coil 4096, value 0x0001
    EXPECT_EQ(plan(unit, strict, Bytes{0x03, 0x10, 0x00, 0x00}),
              Plan{Exception::illegal_data_value});  // mis-sized read of register 4096
}

TEST(GatewayPrecedence, AddressBeforeUnconfiguredModule) {
    const auto unit = ioport_unit({});  // mux8m 7 not configured
    EXPECT_EQ(plan(unit, strict, write_registers(23, {0, 0})),
              Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_register(23, 0)), Plan{Exception::illegal_data_address});
}

TEST(GatewayPrecedence, AddressBeforeBadValue) {
    const auto unit = ioport_unit({mux8m(6), mux8m(7)});
    EXPECT_EQ(plan(unit, strict, write_registers(22, {0x0909, 0x0909, 0x0909})),
              Plan{Exception::illegal_data_address});
}

TEST(GatewayPrecedence, UnconfiguredModuleBeforeBadValue) {
    const auto unit = ioport_unit({rgbdm(0)});
    EXPECT_EQ(plan(unit, strict, write_register(9, 9)), Plan{Exception::illegal_data_address});
    // rgbdm 0 has the bad value, rgbdm 1 is not configured: 02 wins.
    EXPECT_EQ(plan(unit, strict, write_registers(8, {9, 1})),
              Plan{Exception::illegal_data_address});
}

TEST(GatewayPrecedence, BadValueBeforePortClosed) {
    const auto unit = ioport_unit({rgbdm(0)}, false);
    EXPECT_EQ(plan(unit, strict, write_register(8, 8)), Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, write_register(8, 7)), Plan{Exception::gateway_target_failed});
}

TEST(GatewayPrecedence, AddressBeforeStale) {
    auto unit = ioport_unit({});
    set(unit, dcvim(7), ModuleStatus::no_answer);
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 79, 1)),
              Plan{Exception::gateway_target_failed});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 79, 2)),
              Plan{Exception::illegal_data_address});
}

// --- ID-2 -------------------------------------------------------------------------------------

TEST(GatewayId2, Coil0WrittenWith1ResetsTheCounter) {
    const auto unit = id2_unit();
    EXPECT_EQ(plan(unit, strict, write_coil(0, true)), reset_plan());
    EXPECT_EQ(plan(unit, strict, write_coils(0, {1})), reset_plan());
    // Offline device, open port: still sent.
    EXPECT_EQ(plan(id2_unit(ModuleStatus::no_answer), strict, write_coil(0, true)), reset_plan());
}

TEST(GatewayId2, Coil0WrittenWith0DoesNothingEvenWithThePortClosed) {
    EXPECT_EQ(plan(id2_unit(), strict, write_coil(0, false)), Plan{WritePlan{}});
    EXPECT_EQ(plan(id2_unit(), strict, write_coils(0, {0})), Plan{WritePlan{}});
    const auto closed = id2_unit(ModuleStatus::no_answer, false);
    EXPECT_EQ(plan(closed, strict, write_coil(0, false)), Plan{WritePlan{}});
    EXPECT_EQ(plan(closed, strict, write_coil(0, true)), Plan{Exception::gateway_target_failed});
}

TEST(GatewayId2, Coil0Rules) {
    const auto unit = id2_unit(ModuleStatus::no_answer);
    EXPECT_EQ(plan(unit, read_only, write_coil(0, true)), Plan{Exception::illegal_function});
    EXPECT_EQ(plan(unit, strict, Bytes{0x05, 0x00, 0x00, 0x00, 0x01}),
              Plan{Exception::illegal_data_value});
    EXPECT_EQ(plan(unit, strict, write_coils(0, {1, 1})), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_coil(1, true)), Plan{Exception::illegal_data_address});
    // Coil 0 is a command, not data: reading it never answers 0B.
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::coils, 0, 1)), ok_read());
}

TEST(GatewayId2, NoHoldingRegisters) {
    const auto unit = id2_unit();
    EXPECT_EQ(plan(unit, strict, write_register(0, 1)), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, write_registers(0, {1})), Plan{Exception::illegal_data_address});
    EXPECT_EQ(plan(unit, strict, read_pdu(Table::holding_registers, 0, 1)),
              Plan{Exception::illegal_data_address});
}

TEST(GatewayId2, StopInputAndCounterAreStaleWhenTheDeviceIsNotOnline) {
    for (const auto status :
         {ModuleStatus::no_answer, ModuleStatus::bad_answer, ModuleStatus::not_polled}) {
        const auto unit = id2_unit(status);
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::discrete_inputs, 0, 1)),
                  Plan{Exception::gateway_target_failed});
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 0, 1)),
                  Plan{Exception::gateway_target_failed});
        EXPECT_EQ(plan(unit, hold, read_pdu(Table::input_registers, 0, 1)), ok_read());
        EXPECT_EQ(plan(unit, strict, read_pdu(Table::input_registers, 1100, 72)), ok_read(true));
    }
    EXPECT_EQ(plan(id2_unit(), strict, read_pdu(Table::input_registers, 0, 1)), ok_read());
}

// --- The printed map --------------------------------------------------------------------------

TEST(GatewayMap, ModiconNumbers) {
    EXPECT_EQ(modicon_number(Table::coils, 0), "000001");
    EXPECT_EQ(modicon_number(Table::coils, 127), "000128");
    EXPECT_EQ(modicon_number(Table::discrete_inputs, 0), "100001");
    EXPECT_EQ(modicon_number(Table::discrete_inputs, 1000), "101001");
    EXPECT_EQ(modicon_number(Table::holding_registers, 23), "400024");
    EXPECT_EQ(modicon_number(Table::input_registers, 0), "300001");
    EXPECT_EQ(modicon_number(Table::input_registers, 1271), "301272");
}

UnitMap small_ioport() {
    return {UnitKind::ioport, 1, "hub0", {dim16(0), dom16(0), acm3p(0), rgbdm(0), mux8m(0)}};
}

const MapRow* find_row(const std::vector<MapRow>& rows, Table table, std::uint16_t address) {
    for (const auto& row : rows)
        if (row.table == table && row.address == address) return &row;
    return nullptr;
}

TEST(GatewayMap, RowsOfASmallIoportUnit) {
    const auto rows = map_rows(small_ioport());
    const auto count = [&](Table table) {
        return std::count_if(rows.begin(), rows.end(),
                             [&](const MapRow& row) { return row.table == table; });
    };
    EXPECT_EQ(count(Table::coils), 16);                // dom16 0
    EXPECT_EQ(count(Table::discrete_inputs), 16 + 5);  // dim16 0, online of 5 slots
    EXPECT_EQ(count(Table::holding_registers), 3);     // dom16, rgbdm, mux8m
    // dim16 word, acm3p raw and float, the 13 link rows (6 of §2.3, 7 of §5.1), status, age
    EXPECT_EQ(count(Table::input_registers), 1 + 3 + 3 + 13 + 5 + 5);
    EXPECT_EQ(rows.size(), 70U);
    EXPECT_TRUE(std::is_sorted(rows.begin(), rows.end(), [](const MapRow& a, const MapRow& b) {
        return std::pair{a.table, a.address} < std::pair{b.table, b.address};
    }));
    for (const auto& row : rows)
        EXPECT_EQ(row.unit_id, 1);
}

TEST(GatewayMap, ExactRows) {
    const auto rows = map_rows(small_ioport());
    ASSERT_FALSE(rows.empty());
    const auto& first = rows.front();
    EXPECT_EQ(first.table, Table::coils);
    EXPECT_EQ(first.address, 0);
    EXPECT_EQ(first.module, "dom16 0");
    EXPECT_EQ(first.channel, "o0");
    EXPECT_EQ(first.data_type, "bit");
    EXPECT_EQ(first.units, "");
    EXPECT_EQ(first.access, "read/write");
    EXPECT_EQ(first.description, "output 0");

    const auto* input = find_row(rows, Table::discrete_inputs, 15);
    ASSERT_NE(input, nullptr);
    EXPECT_EQ(input->module, "dim16 0");
    EXPECT_EQ(input->channel, "i15");
    EXPECT_EQ(input->access, "read");

    const auto* percent = find_row(rows, Table::input_registers, 202);
    ASSERT_NE(percent, nullptr);
    EXPECT_EQ(percent->module, "acm3p 0");
    EXPECT_EQ(percent->channel, "c1");
    EXPECT_EQ(percent->data_type, "float32");
    EXPECT_EQ(percent->units, "%");
    EXPECT_EQ(find_row(rows, Table::input_registers, 203), nullptr);  // second word, no row

    const auto* raw = find_row(rows, Table::input_registers, 18);
    ASSERT_NE(raw, nullptr);
    EXPECT_EQ(raw->channel, "c2");
    EXPECT_EQ(raw->data_type, "uint16");
    EXPECT_EQ(raw->units, "");

    const auto* colour = find_row(rows, Table::holding_registers, 8);
    ASSERT_NE(colour, nullptr);
    EXPECT_EQ(colour->module, "rgbdm 0");
    EXPECT_EQ(colour->channel, "");
    EXPECT_EQ(colour->access, "read/write");
    EXPECT_EQ(colour->description,
              "colour: 0 off, 1 red, 2 green, 3 blue, 4 cyan, 5 magenta, 6 yellow, 7 white");

    const auto* cycles = find_row(rows, Table::input_registers, 1002);
    ASSERT_NE(cycles, nullptr);
    EXPECT_EQ(cycles->module, "link hub0");
    EXPECT_EQ(cycles->data_type, "uint32");
    EXPECT_EQ(find_row(rows, Table::input_registers, 1003), nullptr);
    const auto* cycle_time = find_row(rows, Table::input_registers, 1001);
    ASSERT_NE(cycle_time, nullptr);
    EXPECT_EQ(cycle_time->units, "0.1 ms");
    EXPECT_EQ(cycle_time->data_type, "uint16");

    const auto* age = find_row(rows, Table::input_registers, 1208);  // dom16 0 is slot 8
    ASSERT_NE(age, nullptr);
    EXPECT_EQ(age->module, "dom16 0");
    EXPECT_EQ(age->units, "ms");
    EXPECT_NE(find_row(rows, Table::input_registers, 1116), nullptr);  // acm3p 0
    EXPECT_NE(find_row(rows, Table::discrete_inputs, 1064), nullptr);  // mux8m 0
    EXPECT_EQ(find_row(rows, Table::input_registers, 1101), nullptr);  // dim16 1: none
    EXPECT_EQ(find_row(rows, Table::discrete_inputs, 16), nullptr);
}

TEST(GatewayMap, SingleChannelAnalogModules) {
    const auto rows = map_rows({UnitKind::ioport, 3, "hub1", {dccim(1), dcvim(7)}});
    const auto* amperes = find_row(rows, Table::input_registers, 298);
    ASSERT_NE(amperes, nullptr);
    EXPECT_EQ(amperes->module, "dccim 1");
    EXPECT_EQ(amperes->channel, "");
    EXPECT_EQ(amperes->units, "A");
    EXPECT_EQ(amperes->unit_id, 3);
    const auto* volts = find_row(rows, Table::input_registers, 326);
    ASSERT_NE(volts, nullptr);
    EXPECT_EQ(volts->units, "V");
    EXPECT_NE(find_row(rows, Table::input_registers, 65), nullptr);
    EXPECT_NE(find_row(rows, Table::input_registers, 79), nullptr);
    EXPECT_EQ(rows.size(), 2U * 5 + 13);  // raw, float, status, age, online per module; link
}

TEST(GatewayMap, Id2Rows) {
    const auto rows = map_rows({UnitKind::id2, 2, "press", {}});
    ASSERT_EQ(rows.size(), 19U);  // coil, DI, DI 1000, IR, 13 link, 1100, 1200
    EXPECT_EQ(rows[0].table, Table::coils);
    EXPECT_EQ(rows[0].module, "ID-2");
    EXPECT_EQ(rows[0].access, "write");
    EXPECT_EQ(rows[1].table, Table::discrete_inputs);
    EXPECT_EQ(rows[1].address, 0);
    EXPECT_EQ(rows[1].description, "machine-stop input");
    EXPECT_EQ(rows[2].address, 1000);
    EXPECT_EQ(rows[3].table, Table::input_registers);
    EXPECT_EQ(rows[3].address, 0);
    EXPECT_EQ(rows[3].module, "ID-2");
    EXPECT_EQ(rows[4].module, "link press");
    EXPECT_EQ(rows[10].address, 1010);
    EXPECT_EQ(rows[10].data_type, "uint32");
    EXPECT_EQ(rows[16].address, 1020);
    EXPECT_EQ(rows[16].description,
              "communication loss: 0 normal, 1 outputs were put in their safe state");
    EXPECT_EQ(rows[17].address, 1100);
    EXPECT_EQ(rows[17].module, "ID-2");
    EXPECT_EQ(rows[18].address, 1200);
}

TEST(GatewayMap, Markdown) {
    const auto rows = map_rows(small_ioport());
    const auto text = format_markdown(rows);
    const std::string header =
        "| table | PDU address | Modicon | unit | module | channel | type | units | access | "
        "description | module name | channel name |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    ASSERT_EQ(text.substr(0, header.size()), header);
    EXPECT_EQ(text.substr(header.size(), text.find('\n', header.size()) + 1 - header.size()),
              "| coils | 0 | 000001 | 1 | dom16 0 | o0 | bit |  | read/write | output 0 | dom16 0 "
              "|  |\n");
    EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 2 + 70);
    // A | inside a cell would end it.
    EXPECT_NE(text.find("| 16 | 400017 | 1 | mux8m 0 |  | uint16 |  | read/write | (pos << 8) "
                        "\\| neg"),
              std::string::npos)
        << text;
    EXPECT_NE(text.find("| input registers | 200 | 300201 | 1 | acm3p 0 | c0 | float32 | % | "
                        "read |"),
              std::string::npos);
}

TEST(GatewayMap, Csv) {
    const auto rows = map_rows(small_ioport());
    const auto text = format_csv(rows);
    const std::string header =
        "table,PDU address,Modicon,unit,module,channel,type,units,access,description,module "
        "name,channel name\r\n";
    ASSERT_EQ(text.substr(0, header.size()), header);
    EXPECT_EQ(text.substr(header.size(), text.find('\n', header.size()) + 1 - header.size()),
              "coils,0,000001,1,dom16 0,o0,bit,,read/write,output 0,dom16 0,\r\n");
    EXPECT_EQ(std::count(text.begin(), text.end(), '\n'), 1 + 70);
    EXPECT_NE(text.find("holding registers,8,400009,1,rgbdm 0,,uint16,,read/write,\"colour: 0 "
                        "off, 1 red,"),
              std::string::npos)
        << text;
}

TEST(GatewayMap, CsvQuotesOnlyWhatNeedsIt) {
    const std::vector<MapRow> rows{{Table::input_registers, 7, 9, "a \"b\"", "x,y", "uint16", "",
                                    "read", "plain", "m, 1", "°C"}};
    EXPECT_EQ(format_csv(rows),
              "table,PDU address,Modicon,unit,module,channel,type,units,access,description,module "
              "name,channel name\r\n"
              "input registers,7,300008,9,\"a \"\"b\"\"\",\"x,y\",uint16,,read,plain,\"m, 1\","
              "°C\r\n");
}

// gateway.md §6.1: names, units and scales in the map, after the ten columns of §4.
TEST(GatewayMap, RowsCarryNamesUnitsAndScales) {
    auto unit = small_ioport();
    for (const auto module : unit.modules)
        unit.tags.push_back(default_tags(module));
    unit.tags[0].points[5] = "pump running";  // dim16 0
    unit.tags[1].points[0] = "horn";          // dom16 0
    unit.tags[2].name = "boiler 1";           // acm3p 0
    unit.tags[2].channels[0] = {"supply temperature", "°C", Scale{0, 100, -20, 150}, {-20, 150}};
    const auto rows = map_rows(unit);

    const auto* value = find_row(rows, Table::input_registers, 200);
    ASSERT_NE(value, nullptr);
    EXPECT_EQ(value->module, "acm3p 0");  // §4's columns as they were
    EXPECT_EQ(value->channel, "c0");
    EXPECT_EQ(value->units, "°C");
    EXPECT_EQ(value->description, "channel 0: raw / 65535 * 100 %, scaled [0, 100] to [-20, 150]");
    EXPECT_EQ(value->module_name, "boiler 1");
    EXPECT_EQ(value->channel_name, "supply temperature");
    const auto* raw = find_row(rows, Table::input_registers, 16);
    ASSERT_NE(raw, nullptr);
    EXPECT_EQ(raw->channel_name, "supply temperature");
    EXPECT_EQ(raw->units, "");
    const auto* unscaled = find_row(rows, Table::input_registers, 202);
    ASSERT_NE(unscaled, nullptr);
    EXPECT_EQ(unscaled->units, "%");
    EXPECT_EQ(unscaled->channel_name, "");
    EXPECT_EQ(find_row(rows, Table::input_registers, 1116)->module_name, "boiler 1");  // status
    EXPECT_EQ(find_row(rows, Table::discrete_inputs, 5)->channel_name, "pump running");
    EXPECT_EQ(find_row(rows, Table::discrete_inputs, 4)->channel_name, "");
    EXPECT_EQ(find_row(rows, Table::coils, 0)->channel_name, "horn");
    EXPECT_EQ(find_row(rows, Table::input_registers, 1002)->module_name, "");  // the link's
    EXPECT_NE(format_markdown(rows).find("| read | channel 0: raw / 65535 * 100 %, scaled [0, "
                                         "100] to [-20, 150] | boiler 1 | supply temperature |"),
              std::string::npos);
}

}  // namespace
}  // namespace ioport::gateway
