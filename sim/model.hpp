// What the simulated devices know and answer: an ioport hub with any set of modules, or an
// ID-2. Pure: bytes in, answers out; timing and the pty live in simulator.hpp.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <optional>
#include <random>
#include <string>
#include <variant>
#include <vector>

#include "protocol/error.hpp"
#include "protocol/framer.hpp"
#include "protocol/id2.hpp"
#include "protocol/ioport.hpp"

namespace ioport::sim {

enum class FaultKind {
    none,
    silent,       // no answer at all
    error_ack,    // an output answers "0" and changes nothing; an input is silent
    garbage,      // random non-hex bytes and a CR
    short_reply,  // the right answer less its last character
    long_reply,   // the right answer with one character too many
    delay,        // the right answer, `delay` late (past the master's timeout: a late answer)
};
std::string_view name(FaultKind kind);
std::optional<FaultKind> fault_kind_from_name(std::string_view text);

struct Fault {
    FaultKind kind = FaultKind::none;
    double probability = 1.0;  // of each transaction being hit
    std::chrono::microseconds delay{};
};

struct Answer {
    std::string bytes;  // terminator included
    std::chrono::microseconds extra_delay{};
};

struct LogEntry {
    std::chrono::microseconds at;  // since the simulator started
    std::string request;           // as received, without terminator
    std::string answer;            // as sent, "" when silent
};

enum class Protocol { ioport, id2 };

// Module state of a hub: inputs as the raw words the module reports, outputs as their
// 16-bit value (dom16 word, rgbdm colour code, mux8m (pos << 8) | neg).
struct ModuleState {
    bool present = false;
    std::array<std::uint16_t, 3> raw{};
    Fault fault;
};

class DeviceModel {
  public:
    DeviceModel(Protocol protocol, std::uint64_t seed);

    Protocol protocol() const { return protocol_; }

    // Feeds bytes from the master; returns the answers due, in order (silence yields none).
    std::vector<Answer> receive(std::string_view bytes, std::chrono::microseconds now);

    // --- hub ---
    Result<> add(ModuleAddress module);
    Result<> remove(ModuleAddress module);
    std::vector<ModuleAddress> modules() const;
    // Inputs' raw words, or an output's value (as after a reset of the module).
    Result<> set_values(ModuleAddress module, std::span<const std::uint16_t> raw);
    Result<std::vector<std::uint16_t>> values(ModuleAddress module) const;
    Result<> set_fault(ModuleAddress module, Fault fault);

    // --- ID-2 ---
    bool stop_input() const { return stop_input_; }
    void set_stop_input(bool high) { stop_input_ = high; }
    std::uint16_t counter() const { return counter_; }
    void set_counter(std::uint16_t count) { counter_ = count; }
    void pulse(unsigned count);  // the counter wraps at 65535 like a 16-bit register

    // A fault on every module (hub) or on every command of the device (ID-2).
    void set_fault_all(Fault fault);
    // A fault on one ID-2 command alone: a device whose counter stops answering while its stop
    // input still does.
    Result<> set_id2_fault(id2::Command command, Fault fault);

    // Faults that hit a transaction since the start, by kind (index: FaultKind).
    const std::array<std::uint64_t, 7>& injected() const { return injected_; }

    const std::deque<LogEntry>& log() const { return log_; }
    void clear_log() { log_.clear(); }

  private:
    std::optional<Answer> answer_hub(std::string_view frame);
    std::optional<Answer> answer_id2(char request);
    // The answer `fault` turns `good` into; `apply` tells whether a command takes effect.
    std::optional<Answer> apply_fault(const Fault& fault, std::string good, bool& apply);
    Result<ModuleState*> present(ModuleAddress module);
    void record(std::chrono::microseconds now, std::string request, const std::optional<Answer>&);

    Protocol protocol_;
    LineFramer framer_;
    std::array<ModuleState, slot_count> modules_{};
    bool stop_input_ = false;
    std::uint16_t counter_ = 0;
    std::array<Fault, 3> id2_faults_{};  // stop input, count, reset
    std::mt19937_64 rng_;
    std::array<std::uint64_t, 7> injected_{};
    std::deque<LogEntry> log_;
};

inline constexpr std::size_t log_capacity = 100000;

}  // namespace ioport::sim
