#include "tools/ctl.hpp"

#include <array>
#include <charconv>
#include <vector>

#include <fmt/format.h>

#include "config/command_line.hpp"
#include "config/duration.hpp"
#include "config/number.hpp"
#include "link/blocking_link.hpp"
#include "protocol/exchange.hpp"

#ifndef IOPORTD_VERSION
#define IOPORTD_VERSION "unknown"
#endif

namespace ioport::ctl {

const std::string_view usage = R"(Usage: ioportctl [OPTIONS] COMMAND [ARGS]

Direct access to ioport modules on a hub8u/hub8r, and to an ID-2 interface.

Commands:
  read MODULE                  read an input module: dim16 lim16 acm3p acm3c dccim dcvim,
                               e.g. read dim16:0, read acm3p:1
  write dom16:N WORD           set all 16 outputs; WORD as 0x93D1, 37841 or 0b1001001111010001
  write dom16:N OUTPUT on|off  switch output 0-15 on or off. A dom16 cannot be read back, so
                               the other 15 outputs are switched OFF: give the whole word to
                               keep them
  rgb N COLOUR                 rgbdm N: off red green blue cyan magenta yellow white, or 0-7
  mux N POS NEG                mux8m N: test point POS (0-7) on dev+, NEG (0-7) on dev-
  mux N off                    mux8m N: disconnect all test points
  id2 stop|count|reset         the ID-2: stop input, pulse counter, counter reset (9600 baud)
  scan                         probe the 48 input module addresses and list the modules that
                               answer. Output modules are not probed: their only command sets
                               their outputs, and they cannot be read back (see --reset-outputs)

Options:
  -p, --port PATH      serial device (default: $IOPORT_PORT, else /dev/ttyUSB0)
  -b, --baud N         115200 or 38400 for a hub (default 115200); 9600 for id2 (default)
  -t, --timeout DUR    per attempt, e.g. 100ms (default 100ms; scan 30ms; id2 200ms)
  -r, --retries N      extra attempts after no answer or a bad answer (default 1; scan 0)
      --reset-outputs  scan: probe the output modules too, by sending them their off state
                       (dom16 0x0000, rgbdm off, mux8m disconnected): a running plant's
                       outputs are switched off
      --inputs-only    scan: probe input modules only, send nothing to outputs (the default)
      --json           machine-readable output on stdout
  -h, --help           this text
  -V, --version        the version

Exit status:
  0 done   1 the device refused (error ack) or answered garbage   2 usage error
  3 port not found   4 permission denied or port in use   5 no answer   6 port lost, I/O error
)";

namespace {

Error usage_error(const std::string& message) {
    return {Errc::invalid_argument, message + "\n(ioportctl --help lists the commands)"};
}

// The long options without a letter.
enum : int { json = 256, inputs_only, reset_outputs };

constexpr std::array<option, 9> long_options{{
    {"help", no_argument, nullptr, 'h'},
    {"version", no_argument, nullptr, 'V'},
    {"port", required_argument, nullptr, 'p'},
    {"baud", required_argument, nullptr, 'b'},
    {"timeout", required_argument, nullptr, 't'},
    {"retries", required_argument, nullptr, 'r'},
    {"json", no_argument, nullptr, json},
    {"inputs-only", no_argument, nullptr, inputs_only},
    {"reset-outputs", no_argument, nullptr, reset_outputs},
}};

Result<std::uint8_t> module_number(std::string_view text, std::string_view type) {
    const auto n = parse_unsigned(text, modules_per_type - 1);
    if (!n)
        return Unexpected(
            usage_error(fmt::format("'{}' is not a {} module number: use 0-7", text, type)));
    return static_cast<std::uint8_t>(*n);
}

Result<ModuleAddress> module_of_type(std::string_view text, std::string_view want,
                                     bool (*accept)(ModuleType)) {
    auto module = parse_module_address(text);
    if (!module) return Unexpected(usage_error(module.error().message));
    if (!accept(module->type))
        return Unexpected(usage_error(fmt::format("{} is not {}", to_string(*module), want)));
    return module;
}

Result<Command> parse_write(const std::vector<std::string_view>& words) {
    if (words.size() != 3 && words.size() != 4)
        return Unexpected(usage_error("write takes dom16:N WORD, or dom16:N OUTPUT on|off"));
    auto module = module_of_type(words[1], "a dom16: rgb and mux set the other outputs",
                                 [](ModuleType t) { return t == ModuleType::dom16; });
    if (!module) return Unexpected(module.error());
    if (words.size() == 3) {
        const auto word = parse_unsigned(words[2], 0xFFFF);
        if (!word)
            return Unexpected(usage_error(fmt::format(
                "'{}' is not a 16-bit word: use 0x93D1, 37841 or 0b1001001111010001", words[2])));
        return Write{*module, static_cast<std::uint16_t>(*word), std::nullopt};
    }
    const auto output = parse_unsigned(words[2], 15);
    if (!output)
        return Unexpected(
            usage_error(fmt::format("'{}' is not a dom16 output: use 0-15", words[2])));
    if (words[3] != "on" && words[3] != "off" && words[3] != "1" && words[3] != "0")
        return Unexpected(usage_error(fmt::format("'{}': say on or off", words[3])));
    const bool on = words[3] == "on" || words[3] == "1";
    return Write{*module, static_cast<std::uint16_t>(on ? 1U << *output : 0U),
                 static_cast<int>(*output)};
}

Result<Command> parse_rgb(const std::vector<std::string_view>& words) {
    if (words.size() != 3) return Unexpected(usage_error("rgb takes N COLOUR"));
    const auto number = module_number(words[1], "rgbdm");
    if (!number) return Unexpected(number.error());
    auto colour = colour_from_name(words[2]);
    if (const auto code = parse_unsigned(words[2], colour_count - 1); !colour && code)
        colour = static_cast<Colour>(*code);
    if (!colour)
        return Unexpected(usage_error(fmt::format(
            "'{}' is not a colour: off red green blue cyan magenta yellow white, or 0-7",
            words[2])));
    return Write{{ModuleType::rgbdm, *number}, static_cast<std::uint16_t>(*colour), std::nullopt};
}

Result<Command> parse_mux(const std::vector<std::string_view>& words) {
    if (words.size() != 3 && words.size() != 4)
        return Unexpected(usage_error("mux takes N POS NEG, or N off"));
    const auto number = module_number(words[1], "mux8m");
    if (!number) return Unexpected(number.error());
    if (words.size() == 3) {
        if (words[2] != "off") return Unexpected(usage_error("mux takes N POS NEG, or N off"));
        return Write{{ModuleType::mux8m, *number}, 0, std::nullopt};
    }
    const auto pos = parse_unsigned(words[2], mux_test_points - 1);
    const auto neg = parse_unsigned(words[3], mux_test_points - 1);
    if (!pos || !neg)
        return Unexpected(usage_error(
            fmt::format("mux test points '{}' '{}': each must be 0-7", words[2], words[3])));
    return Write{
        {ModuleType::mux8m, *number},
        MuxSetting{static_cast<std::uint8_t>(*pos), static_cast<std::uint8_t>(*neg)}.value(),
        std::nullopt};
}

Result<Command> parse_command(const std::vector<std::string_view>& words) {
    if (words.empty()) return Unexpected(usage_error("no command given"));
    const auto verb = words[0];
    if (verb == "read") {
        if (words.size() != 2) return Unexpected(usage_error("read takes one MODULE"));
        auto module = module_of_type(words[1], "an input module: rgb, mux and write set outputs",
                                     [](ModuleType t) { return !is_output(t); });
        if (!module) return Unexpected(module.error());
        return Read{*module};
    }
    if (verb == "write") return parse_write(words);
    if (verb == "rgb") return parse_rgb(words);
    if (verb == "mux") return parse_mux(words);
    if (verb == "id2") {
        const std::string_view what = words.size() == 2 ? words[1] : "";
        if (what == "stop") return Id2{id2::Command::stop_input};
        if (what == "count") return Id2{id2::Command::count};
        if (what == "reset") return Id2{id2::Command::reset};
        return Unexpected(usage_error("id2 takes stop, count or reset"));
    }
    if (verb == "scan") {
        if (words.size() != 1) return Unexpected(usage_error("scan takes no arguments"));
        return Scan{};
    }
    return Unexpected(usage_error(fmt::format("unknown command '{}'", verb)));
}

// --- running ----------------------------------------------------------------------------------

int exit_code(Errc code) {
    switch (code) {
        case Errc::error_ack:
        case Errc::malformed:
            return exit_refused;
        case Errc::invalid_argument:
            return exit_usage;
        case Errc::port_not_found:
            return exit_no_port;
        case Errc::permission_denied:
        case Errc::port_busy:
            return exit_no_permission;
        case Errc::timeout:
        case Errc::line_noisy:
            return exit_no_answer;
        case Errc::port_lost:
        case Errc::port_closed:
        case Errc::io_error:
        case Errc::no_space:
        case Errc::cancelled:
            break;
    }
    return exit_io;
}

int report(const Error& error, std::ostream& err) {
    err << "ioportctl: " << error.message << "\n";
    return exit_code(error.code);
}

LinkSettings settings_for(const Options& options, bool id2, bool scan) {
    LinkSettings settings;
    settings.device = options.port;
    settings.baud = options.baud.value_or(id2 ? 9600 : 115200);
    settings.timeout = options.timeout.value_or(id2 ? 200ms : scan ? 30ms : 100ms);
    settings.retries = options.retries.value_or(scan ? 0 : 1);
    return settings;
}

std::string bits_on(std::uint16_t word, char prefix) {
    std::vector<std::string> on;
    for (int k = 0; k < 16; ++k)
        if (word >> k & 1U) on.push_back(fmt::format("{}{}", prefix, k));
    return on.empty() ? "none" : fmt::format("{}", fmt::join(on, " "));
}

void print_reading(ModuleAddress module, const Reading& reading, long long round_trip_us, bool json,
                   std::ostream& out) {
    const auto type = module.type;
    const std::span raw(reading.raw.data(), static_cast<std::size_t>(reading.count));
    if (json) {
        std::string fields;
        if (type == ModuleType::dim16 || type == ModuleType::lim16) {
            std::vector<std::string_view> inputs;
            inputs.reserve(16);
            for (int k = 0; k < 16; ++k)
                inputs.push_back(raw[0] >> k & 1U ? "true" : "false");
            fields = fmt::format(R"(,"inputs":[{}])", fmt::join(inputs, ","));
        } else {
            std::vector<std::string> values;
            for (const auto word : raw)
                values.push_back(fmt::format("{}", engineering_value(type, word)));
            fields = fmt::format(R"(,"values":[{}],"unit":"{}")", fmt::join(values, ","),
                                 symbol(engineering_unit(type)));
        }
        out << fmt::format(R"({{"module":"{}","number":{},"raw":[{}]{},"round_trip_us":{}}})",
                           name(type), module.number, fmt::join(raw, ","), fields, round_trip_us)
            << "\n";
        return;
    }
    if (type == ModuleType::dim16 || type == ModuleType::lim16) {
        out << fmt::format("{}  0x{:04X}  on: {}\n", to_string(module), raw[0],
                           bits_on(raw[0], 'i'));
        return;
    }
    const int decimals = engineering_unit(type) == Unit::percent ? 2 : 3;
    if (raw.size() == 1) {
        out << fmt::format("{}  {:5}  {:.{}f} {}\n", to_string(module), raw[0],
                           engineering_value(type, raw[0]), decimals,
                           symbol(engineering_unit(type)));
        return;
    }
    out << to_string(module) << "\n";
    for (std::size_t c = 0; c < raw.size(); ++c)
        out << fmt::format("  c{}  {:5}  {:6.{}f} {}\n", c, raw[c], engineering_value(type, raw[c]),
                           decimals, symbol(engineering_unit(type)));
}

std::string describe_write(const Write& write) {
    switch (write.module.type) {
        case ModuleType::rgbdm:
            return std::string(name(static_cast<Colour>(write.value)));
        case ModuleType::mux8m: {
            const auto mux = *mux_from_value(write.value);
            return mux.disconnected() ? "all test points disconnected"
                                      : fmt::format("tp{} on dev+, tp{} on dev-", mux.pos, mux.neg);
        }
        case ModuleType::dom16:
            return fmt::format("outputs 0x{:04X} (on: {})", write.value, bits_on(write.value, 'o'));
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;  // a Write is to an output module
    }
    return fmt::format("0x{:04X}", write.value);
}

int run_exchange(BlockingLink& link, const Exchange& exchange, const Invocation& invocation,
                 std::ostream& out, std::ostream& err) {
    const auto reading = link.transact(exchange);
    if (!reading) return report(reading.error(), err);
    const auto rtt = link.last_round_trip().count();
    const bool json = invocation.options.json;
    if (const auto* read = std::get_if<Read>(&invocation.command)) {
        print_reading(read->module, *reading, rtt, json, out);
    } else if (const auto* write = std::get_if<Write>(&invocation.command)) {
        if (json)
            out << fmt::format(
                       R"({{"module":"{}","number":{},"value":{},"ack":true,"round_trip_us":{}}})",
                       name(write->module.type), write->module.number, write->value, rtt)
                << "\n";
        else
            out << fmt::format("{}: {}\n", to_string(write->module), describe_write(*write));
        if (write->single_output && !json)
            err << "ioportctl: note: the other outputs of " << to_string(write->module)
                << " are now off\n";
    } else {
        const auto command = std::get<Id2>(invocation.command).command;
        const auto value = reading->count ? reading->raw[0] : 0;
        if (json) {
            const std::string_view key = command == id2::Command::stop_input ? "stop_input"
                                         : command == id2::Command::count    ? "count"
                                                                             : "reset";
            out << fmt::format(R"({{"{}":{},"round_trip_us":{}}})", key,
                               command == id2::Command::reset ? "true" : fmt::format("{}", value),
                               rtt)
                << "\n";
        } else if (command == id2::Command::stop_input) {
            out << fmt::format("ID-2 stop input: {} ({})\n", value, value ? "high" : "low");
        } else if (command == id2::Command::count) {
            out << fmt::format("ID-2 counter: {}\n", value);
        } else {
            out << "ID-2 counter reset\n";
        }
    }
    return exit_ok;
}

struct Found {
    ModuleAddress module;
    long long round_trip_us;
    std::string problem;  // empty when the answer was valid
};

// A scan must not change a running plant. Input modules are probed with a read, which changes
// nothing. An output module (dom16, rgbdm, mux8m) has one request, which sets its outputs, and
// none that reads them back (protocol.md §1). Anything else is outside the protocol: a module
// may ignore it (the simulator does, as a strict module would) or act on it. No probe of an
// output module is known to leave it as it is, so output modules are probed only when asked
// (--reset-outputs), by sending them their off state.
int run_scan(BlockingLink& link, const Invocation& invocation, std::ostream& out,
             std::ostream& err) {
    const bool outputs = invocation.options.reset_outputs;
    std::vector<Found> found;
    int probed = 0;
    for (int s = 0; s < slot_count; ++s) {
        const auto module = module_at_slot(s);
        if (is_output(module.type) && !outputs) continue;
        ++probed;
        const auto exchange = make_exchange(module, 0);  // outputs: their off state
        const auto reading = link.transact(*exchange);
        const auto rtt = link.last_round_trip().count();
        if (reading) {
            found.push_back({module, rtt, {}});
            continue;
        }
        switch (reading.error().code) {
            case Errc::timeout:
            case Errc::line_noisy:
                break;  // nothing at this address
            case Errc::error_ack:
            case Errc::malformed:
                found.push_back({module, rtt, reading.error().message});
                break;
            case Errc::invalid_argument:
            case Errc::port_not_found:
            case Errc::permission_denied:
            case Errc::port_busy:
            case Errc::port_lost:
            case Errc::port_closed:
            case Errc::io_error:
            case Errc::no_space:
            case Errc::cancelled:
                return report(reading.error(), err);
        }
    }
    if (invocation.options.json) {
        std::vector<std::string> rows;
        rows.reserve(found.size());
        for (const auto& f : found)
            rows.push_back(fmt::format(
                R"({{"module":"{}","number":{},"round_trip_us":{},"ok":{}}})", name(f.module.type),
                f.module.number, f.round_trip_us, f.problem.empty()));
        out << fmt::format(
                   R"({{"port":"{}","baud":{},"probed":{},"outputs_probed":{},"modules":[{}]}})",
                   link.settings().device, link.settings().baud, probed, outputs,
                   fmt::join(rows, ","))
            << "\n";
        return exit_ok;
    }
    out << "module    round trip\n";
    for (const auto& f : found)
        out << fmt::format("{:<9} {:7.2f} ms{}\n", to_string(f.module),
                           static_cast<double>(f.round_trip_us) / 1000.0,
                           f.problem.empty() ? "" : "  (answered, but: " + f.problem + ")");
    out << fmt::format("{} module(s) answered on {} ({} addresses probed at {} baud)\n",
                       found.size(), link.settings().device, probed, link.settings().baud);
    if (!outputs && !invocation.options.inputs_only)
        out << "Output modules (dom16, rgbdm, mux8m) were not probed: their only command sets "
               "their outputs.\nioportctl scan --reset-outputs probes them by switching them "
               "off.\n";
    if (outputs) out << "The output modules that answered are now off.\n";
    return exit_ok;
}

}  // namespace

Result<Invocation> parse_arguments(std::span<const std::string_view> args,
                                   std::string default_port) {
    Invocation invocation{{std::move(default_port), {}, {}, {}, false, false, false}, Help{}};
    auto& options = invocation.options;
    CommandLine line("ioportctl", args, "hVp:b:t:r:", long_options);
    for (;;) {
        auto next = line.next();
        if (!next) return Unexpected(usage_error(next.error()));
        if (!*next) break;
        const auto& [code, value, name] = **next;
        if (!value && (code == 'p' || code == 'b' || code == 't' || code == 'r'))
            return Unexpected(usage_error(fmt::format("{} needs a value", name)));
        switch (code) {
            case 'h':
                return Invocation{options, Help{}};
            case 'V':
                return Invocation{options, Version{}};
            case json:
                options.json = true;
                break;
            case inputs_only:
                options.inputs_only = true;
                break;
            case reset_outputs:
                options.reset_outputs = true;
                break;
            case 'p':
                options.port = *value;
                break;
            case 'b': {
                const auto baud = parse_unsigned(*value, 115200);
                if (!baud || (*baud != 9600 && *baud != 38400 && *baud != 115200))
                    return Unexpected(usage_error(
                        fmt::format("baud '{}': use 115200 or 38400 (9600 for id2)", *value)));
                options.baud = static_cast<int>(*baud);
                break;
            }
            case 't': {
                const auto timeout = parse_duration(*value);
                if (!timeout || *timeout < 1ms || *timeout > 10s)
                    return Unexpected(usage_error(fmt::format(
                        "timeout '{}': use a duration from 1ms to 10s, e.g. 100ms", *value)));
                options.timeout = *timeout;
                break;
            }
            case 'r': {
                const auto retries = parse_unsigned(*value, 10);
                if (!retries)
                    return Unexpected(usage_error(fmt::format("retries '{}': use 0-10", *value)));
                options.retries = static_cast<int>(*retries);
                break;
            }
            default:  // a code of the table above without its case here
                return Unexpected(usage_error(fmt::format("{} is not implemented", name)));
        }
    }
    auto command = parse_command(line.operands());
    if (!command) return Unexpected(command.error());
    invocation.command = *command;
    if (options.inputs_only && !std::holds_alternative<Scan>(invocation.command))
        return Unexpected(usage_error("--inputs-only goes with scan"));
    if (options.reset_outputs && !std::holds_alternative<Scan>(invocation.command))
        return Unexpected(usage_error("--reset-outputs goes with scan"));
    if (options.inputs_only && options.reset_outputs)
        return Unexpected(
            usage_error("--inputs-only and --reset-outputs contradict each other: give one"));
    return invocation;
}

int run(const Invocation& invocation, std::ostream& out, std::ostream& err) {
    if (std::holds_alternative<Help>(invocation.command)) {
        out << usage;
        return exit_ok;
    }
    if (std::holds_alternative<Version>(invocation.command)) {
        out << "ioportctl " << IOPORTD_VERSION << "\n";
        return exit_ok;
    }
    const bool id2 = std::holds_alternative<Id2>(invocation.command);
    const bool scan = std::holds_alternative<Scan>(invocation.command);
    BlockingLink link(settings_for(invocation.options, id2, scan));
    if (auto opened = link.open(); !opened) return report(opened.error(), err);
    if (scan) return run_scan(link, invocation, out, err);
    Result<Exchange> exchange = std::visit(
        [](const auto& command) -> Result<Exchange> {
            using T = std::decay_t<decltype(command)>;
            if constexpr (std::is_same_v<T, Read>)
                return make_exchange(command.module);
            else if constexpr (std::is_same_v<T, Write>)
                return make_exchange(command.module, command.value);
            else if constexpr (std::is_same_v<T, Id2>)
                return make_exchange(command.command);
            else
                return fail(Errc::invalid_argument, "nothing to send");
        },
        invocation.command);
    if (!exchange) return report(exchange.error(), err);
    return run_exchange(link, *exchange, invocation, out, err);
}

int run_command_line(std::span<const std::string_view> args, std::string default_port,
                     std::ostream& out, std::ostream& err) {
    const auto invocation = parse_arguments(args, std::move(default_port));
    if (!invocation) return report(invocation.error(), err);
    return run(*invocation, out, err);
}

}  // namespace ioport::ctl
