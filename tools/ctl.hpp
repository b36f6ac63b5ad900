// ioportctl: direct module access and commissioning, the command-line face of the Hub client.
#pragma once

#include <chrono>
#include <optional>
#include <ostream>
#include <span>
#include <string>
#include <string_view>
#include <variant>

#include "protocol/error.hpp"
#include "protocol/id2.hpp"
#include "protocol/ioport.hpp"

namespace ioport::ctl {

// Exit status, as documented in --help.
enum Exit : int {
    exit_ok = 0,
    exit_refused = 1,  // error ack or an answer that is not valid
    exit_usage = 2,
    exit_no_port = 3,
    exit_no_permission = 4,  // permission denied, or another program holds the port
    exit_no_answer = 5,
    exit_io = 6,  // port lost, other I/O errors
};

struct Options {
    std::string port;
    std::optional<int> baud;
    std::optional<std::chrono::microseconds> timeout;
    std::optional<int> retries;
    bool json = false;
    bool inputs_only = false;    // scan: the default, said explicitly
    bool reset_outputs = false;  // scan: probe output modules too, by switching them off
};

struct Read {
    ModuleAddress module;
};
struct Write {
    ModuleAddress module;
    std::uint16_t value;  // the output value: dom16 word, colour code, (pos << 8) | neg
    std::optional<int> single_output;  // set by "write dom16:N OUTPUT on|off"
};
struct Id2 {
    id2::Command command;
};
struct Scan {};
struct Help {};
struct Version {};
using Command = std::variant<Read, Write, Id2, Scan, Help, Version>;

struct Invocation {
    Options options;
    Command command;
};

// `default_port` is what --port defaults to ($IOPORT_PORT, else /dev/ttyUSB0).
Result<Invocation> parse_arguments(std::span<const std::string_view> args,
                                   std::string default_port);
int run(const Invocation& invocation, std::ostream& out, std::ostream& err);
// Parses and runs; usage errors go to `err` with exit_usage.
int run_command_line(std::span<const std::string_view> args, std::string default_port,
                     std::ostream& out, std::ostream& err);

extern const std::string_view usage;

}  // namespace ioport::ctl
