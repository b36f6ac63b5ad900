#include "tools/sim_cli.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cstdio>

#include <fmt/format.h>

#include "config/command_line.hpp"
#include "config/duration.hpp"
#include "config/number.hpp"
#include "sim/control_client.hpp"

namespace ioport::sim_cli {

const std::string_view usage = R"(Usage: ioport-sim --link PATH (--hub MODULES | --id2) [OPTIONS]
       ioport-sim ctl SOCKET COMMAND...

Simulates an ioport hub (hub8u/hub8r) with the given modules, or an ID-2 interface, on a
pseudo-terminal reachable at PATH (a symlink, like /dev/serial/by-id/...). Runs until SIGINT or
SIGTERM.

  --link PATH          where to put the symlink to the pty (replaced if it exists)
  --hub MODULES        modules on the hub, e.g. dim16:0,dom16:0-1,acm3p:0
  --id2                an ID-2 stop/counter interface instead of a hub
  --control PATH       Unix socket for the control language (see: ioport-sim ctl SOCKET help)
  --baud N             modelled line speed: 9600, 38400 or 115200 (default 115200; id2 9600)
  --turnaround DUR     from request received to answer start (default 500us)
  --no-line-timing     answer at once, without modelling 10 bits per byte
  --seed N             seed of the random faults (default 1), so a run can be replayed
  --wander PERIOD      every PERIOD (e.g. 20ms), every word of every input module moves to a
                       new value, so that every read of it carries a change (default: off)
  --still MODULES      with --wander, modules left as they are set (by the control socket)
  -h, --help           this text

ctl sends one control command to a running simulator and prints its reply; exit 0 on ok.
)";

namespace {

Error usage_error(const std::string& message) {
    return {Errc::invalid_argument, message + "\n(ioport-sim --help for usage)"};
}

// The long options without a letter.
enum : int {
    long_link = 256,
    long_hub,
    long_id2,
    long_control,
    long_baud,
    long_turnaround,
    long_no_line_timing,
    long_seed,
    long_wander,
    long_still
};

constexpr std::array<option, 11> long_options{{
    {"link", required_argument, nullptr, long_link},
    {"hub", required_argument, nullptr, long_hub},
    {"id2", no_argument, nullptr, long_id2},
    {"control", required_argument, nullptr, long_control},
    {"baud", required_argument, nullptr, long_baud},
    {"turnaround", required_argument, nullptr, long_turnaround},
    {"no-line-timing", no_argument, nullptr, long_no_line_timing},
    {"seed", required_argument, nullptr, long_seed},
    {"wander", required_argument, nullptr, long_wander},
    {"still", required_argument, nullptr, long_still},
    {"help", no_argument, nullptr, 'h'},
}};

// --wander: on the simulator's own thread, every period, each word of each input module not
// held `still` takes a value it did not have (a counter, spread over the words and modules).
class Wanderer {
  public:
    Wanderer(asio::io_context& io, sim::DeviceModel& model, const Serve& serve)
        : model_(model), timer_(io), period_(serve.wander) {
        for (const auto module : serve.modules)
            if (!is_output(module.type) && reply_words(module.type) > 0 &&
                std::find(serve.still.begin(), serve.still.end(), module) == serve.still.end())
                modules_.push_back(module);
        if (period_.count() > 0 && !modules_.empty()) schedule();
    }
    void stop() { timer_.cancel(); }

  private:
    void schedule() {
        timer_.expires_after(period_);
        timer_.async_wait([this](const boost::system::error_code& ec) {
            if (ec) return;
            ++tick_;
            for (const auto module : modules_) {
                std::array<std::uint16_t, 3> words{};
                for (std::size_t w = 0; w < words.size(); ++w)
                    words[w] = static_cast<std::uint16_t>(tick_ + std::size_t{0x5555} * w +
                                                          std::size_t{0x0101} * module.number);
                (void)model_.set_values(
                    module,
                    std::span(words.data(), static_cast<std::size_t>(reply_words(module.type))));
            }
            schedule();
        });
    }

    sim::DeviceModel& model_;
    asio::steady_timer timer_;
    std::chrono::microseconds period_;
    std::vector<ModuleAddress> modules_;
    std::uint16_t tick_ = 0;
};

int serve(const Serve& serve, std::ostream& out, std::ostream& err) {
    sim::DeviceModel model(serve.protocol, serve.seed);
    for (const auto module : serve.modules)
        (void)model.add(module);
    asio::io_context io;
    sim::Simulator simulator(io, model, serve.settings);
    if (auto started = simulator.start(); !started) {
        err << "ioport-sim: " << started.error().message << "\n";
        return 1;
    }
    Wanderer wanderer(io, model, serve);
    asio::signal_set signals(io, SIGINT, SIGTERM);
    signals.async_wait([&](const boost::system::error_code&, int) {
        wanderer.stop();
        simulator.stop();
        io.stop();
    });
    const auto what = serve.protocol == sim::Protocol::id2
                          ? std::string("ID-2")
                          : fmt::format("hub with {} module(s)", serve.modules.size());
    out << fmt::format(
        "ioport-sim: {} on {} -> {}, {} baud{}{}\n", what, serve.settings.link_path,
        simulator.pty_name(), serve.settings.baud,
        serve.settings.line_timing ? "" : " (no line timing)",
        serve.settings.control_path ? ", control " + *serve.settings.control_path : std::string{});
    out.flush();
    io.run();
    return 0;
}

int control(const Control& control, std::ostream& out, std::ostream& err) {
    sim::ControlClient client;
    if (auto connected = client.connect(control.socket); !connected) {
        err << "ioport-sim: " << connected.error().message << "\n";
        return 1;
    }
    const auto reply = client.command(control.command);
    if (!reply) {
        err << "ioport-sim: " << reply.error().message << "\n";
        return 1;
    }
    out << *reply;
    if (!reply->empty() && reply->back() != '\n') out << "\n";
    return 0;
}

}  // namespace

Result<std::vector<ModuleAddress>> parse_module_list(std::string_view text) {
    std::vector<ModuleAddress> modules;
    while (!text.empty()) {
        const auto comma = text.find(',');
        auto item = text.substr(0, comma);
        text = comma == std::string_view::npos ? std::string_view{} : text.substr(comma + 1);
        // TYPE:N-M is shorthand for TYPE:N … TYPE:M.
        const auto dash = item.find('-');
        const auto first = parse_module_address(item.substr(0, dash));
        if (!first) return Unexpected(usage_error(first.error().message));
        int last = first->number;
        if (dash != std::string_view::npos) {
            const auto upper = parse_unsigned(item.substr(dash + 1), modules_per_type - 1);
            if (!upper || *upper < first->number)
                return Unexpected(
                    usage_error(fmt::format("'{}': a range is TYPE:N-M with N <= M <= 7", item)));
            last = static_cast<int>(*upper);
        }
        for (int n = first->number; n <= last; ++n)
            modules.push_back({first->type, static_cast<std::uint8_t>(n)});
    }
    if (modules.empty()) return Unexpected(usage_error("--hub needs at least one module"));
    return modules;
}

Result<Invocation> parse_arguments(std::span<const std::string_view> args) {
    // "ctl SOCKET COMMAND...": the command's words as they are, dashes and all.
    if (!args.empty() && args[0] == "ctl") {
        if (args.size() < 3) return Unexpected(usage_error("ctl takes SOCKET COMMAND..."));
        std::string command;
        for (std::size_t i = 2; i < args.size(); ++i) {
            if (i > 2) command += ' ';
            command += args[i];
        }
        return Control{std::string(args[1]), command};
    }
    Serve serve;
    bool hub = false, id2 = false;
    std::optional<int> baud;
    CommandLine line("ioport-sim", args, "h", long_options);
    for (;;) {
        auto next = line.next();
        if (!next) return Unexpected(usage_error(next.error()));
        if (!*next) break;
        const auto& [code, given, name] = **next;
        if (code == 'h') return Help{};
        if (code == long_id2) {
            id2 = true;
            continue;
        }
        if (code == long_no_line_timing) {
            serve.settings.line_timing = false;
            continue;
        }
        if (!given) return Unexpected(usage_error(fmt::format("{} needs a value", name)));
        const auto value = *given;
        switch (code) {
            case long_link:
                serve.settings.link_path = value;
                break;
            case long_control:
                serve.settings.control_path = std::string(value);
                break;
            case long_hub: {
                auto modules = parse_module_list(value);
                if (!modules) return Unexpected(modules.error());
                serve.modules = std::move(*modules);
                hub = true;
                break;
            }
            case long_baud: {
                const auto speed = parse_unsigned(value, 115200);
                if (!speed || (*speed != 9600 && *speed != 38400 && *speed != 115200))
                    return Unexpected(
                        usage_error(fmt::format("baud '{}': 9600, 38400 or 115200", value)));
                baud = static_cast<int>(*speed);
                break;
            }
            case long_turnaround: {
                const auto turnaround = parse_duration(value);
                if (!turnaround) return Unexpected(usage_error(turnaround.error().message));
                serve.settings.turnaround = *turnaround;
                break;
            }
            case long_seed: {
                const auto seed = parse_unsigned(value, ~0UL);
                if (!seed)
                    return Unexpected(usage_error(fmt::format("seed '{}': a whole number", value)));
                serve.seed = *seed;
                break;
            }
            case long_wander: {
                const auto period = parse_duration(value);
                if (!period) return Unexpected(usage_error(period.error().message));
                if (period->count() <= 0)
                    return Unexpected(usage_error(
                        fmt::format("wander '{}': a period such as 20ms, not zero", value)));
                serve.wander = *period;
                break;
            }
            case long_still: {
                auto modules = parse_module_list(value);
                if (!modules) return Unexpected(modules.error());
                serve.still = std::move(*modules);
                break;
            }
            default:  // a code of the table above without its case here
                return Unexpected(usage_error(fmt::format("{} is not implemented", name)));
        }
    }
    if (!line.operands().empty())
        return Unexpected(
            usage_error(fmt::format("unknown argument '{}'", line.operands().front())));
    if (serve.settings.link_path.empty()) return Unexpected(usage_error("--link PATH is required"));
    if (hub == id2) return Unexpected(usage_error("give either --hub MODULES or --id2"));
    serve.protocol = id2 ? sim::Protocol::id2 : sim::Protocol::ioport;
    serve.settings.baud = baud.value_or(id2 ? 9600 : 115200);
    return serve;
}

int run_command_line(std::span<const std::string_view> args, std::ostream& out, std::ostream& err) {
    const auto invocation = parse_arguments(args);
    if (!invocation) {
        err << "ioport-sim: " << invocation.error().message << "\n";
        return 2;
    }
    if (std::holds_alternative<Help>(*invocation)) {
        out << usage;
        return 0;
    }
    if (const auto* c = std::get_if<Control>(&*invocation)) return control(*c, out, err);
    return serve(std::get<Serve>(*invocation), out, err);
}

}  // namespace ioport::sim_cli
