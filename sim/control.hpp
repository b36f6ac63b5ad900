// The simulator's control language, one command a line, as tests and people type it:
//
//   modules | add MODULE | remove MODULE
//   set MODULE VALUE...       inputs' raw words (decimal or 0x hex); set dim16:0 0x8000;
//                             an output's state as if the module had been reset
//   get MODULE                inputs' raw words, or an output's value (dom16 word, colour, mux)
//   set stop 0|1 | set count N | get stop | get count | pulse N       (ID-2)
//   fault MODULE|all|device KIND [PROBABILITY] [DELAY]   KIND: none silent error-ack garbage
//                                                        short long delay
//   fault I|C|R KIND ...      (ID-2) a fault on one command alone: stop input, count, reset
//   log | log clear | log take   the request log: "<µs since start> <request> <answer>";
//                             take = read and clear at once
//   faults                    how many transactions each fault kind hit since the start:
//                             "silent N error-ack N garbage N short N long N delay N"
//   clock                     "<start> <now>": the simulator's start on CLOCK_MONOTONIC and the
//                             time since then, in µs, to put log times on another process's clock
//   unplug [DURATION] | replug
//   chatter INTERVAL | chatter off   a noisy line: one random non-hex byte every INTERVAL,
//                             whatever the master sends
//   help
//
// Every reply ends with one line starting "ok" or "error"; data lines come before it.
#pragma once

#include <chrono>
#include <optional>
#include <string>
#include <string_view>

#include "sim/model.hpp"

namespace ioport::sim {

struct PortAction {
    enum class Kind { unplug, replug, chatter } kind;
    // unplug: when to plug back in; chatter: the interval between noise bytes (none: stop)
    std::optional<std::chrono::microseconds> after;
};

struct ControlReply {
    std::string text;  // lines, each ending in '\n', the last one "ok…" or "error…"
    std::optional<PortAction> action;
};

ControlReply execute(DeviceModel& model, std::string_view line);

inline constexpr std::string_view control_help =
    "modules | add MODULE | remove MODULE\n"
    "set MODULE VALUE... | get MODULE            (MODULE as dim16:0; values decimal or 0x hex)\n"
    "set stop 0|1 | set count N | get stop | get count | pulse N      (ID-2)\n"
    "fault MODULE|all|device KIND [PROBABILITY] [DELAY]\n"
    "fault I|C|R KIND [PROBABILITY] [DELAY]     (ID-2: one command alone)\n"
    "      KIND: none silent error-ack garbage short long delay\n"
    "log | log clear | log take | faults | clock | unplug [DURATION] | replug\n"
    "chatter INTERVAL | chatter off             (a noise byte every INTERVAL)\n"
    "help\n";

}  // namespace ioport::sim
