// ioport-sim: the device simulator's command line.
#pragma once

#include <chrono>
#include <cstdint>
#include <ostream>
#include <span>
#include <string_view>
#include <variant>
#include <vector>

#include "protocol/error.hpp"
#include "sim/model.hpp"
#include "sim/simulator.hpp"

namespace ioport::sim_cli {

struct Serve {
    sim::SimulatorSettings settings;
    sim::Protocol protocol = sim::Protocol::ioport;
    std::vector<ModuleAddress> modules;
    std::uint64_t seed = 1;
    // --wander: every this often, every word of every input module (but those of `still`) moves
    // to a value it did not have, as a plant's inputs never hold still. 0: values stay as set.
    std::chrono::microseconds wander{0};
    std::vector<ModuleAddress> still;
};
struct Control {
    std::string socket;
    std::string command;
};
struct Help {};
using Invocation = std::variant<Serve, Control, Help>;

// "dim16:0,dom16:0-3,acm3p:1" → the modules.
Result<std::vector<ModuleAddress>> parse_module_list(std::string_view text);
Result<Invocation> parse_arguments(std::span<const std::string_view> args);
int run_command_line(std::span<const std::string_view> args, std::ostream& out, std::ostream& err);

extern const std::string_view usage;

}  // namespace ioport::sim_cli
