#include "sim/control.hpp"

#include <cctype>
#include <charconv>
#include <vector>

#include <fmt/format.h>

#include "config/duration.hpp"
#include "config/number.hpp"

namespace ioport::sim {
namespace {

std::vector<std::string_view> split(std::string_view line) {
    std::vector<std::string_view> words;
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\r'))
            ++i;
        const auto start = i;
        while (i < line.size() && line[i] != ' ' && line[i] != '\t' && line[i] != '\r')
            ++i;
        if (i > start) words.push_back(line.substr(start, i - start));
    }
    return words;
}

ControlReply ok(const std::string& text = {}) {
    return {text + "ok\n", std::nullopt};
}
ControlReply error(std::string_view why) {
    return {fmt::format("error {}\n", why), std::nullopt};
}
ControlReply from(const Result<>& result) {
    return result ? ok() : error(result.error().message);
}

ControlReply set_id2(DeviceModel& model, std::string_view what, std::string_view value) {
    if (what == "stop") {
        const auto high = parse_unsigned(value, 1);
        if (!high) return error("set stop takes 0 or 1");
        model.set_stop_input(*high == 1);
        return ok();
    }
    const auto count = parse_unsigned(value, 65535);
    if (!count) return error("set count takes 0-65535");
    model.set_counter(static_cast<std::uint16_t>(*count));
    return ok();
}

ControlReply set(DeviceModel& model, const std::vector<std::string_view>& words) {
    if (words.size() < 3) return error("set needs a target and a value");
    if (model.protocol() == Protocol::id2) {
        if (words.size() != 3 || (words[1] != "stop" && words[1] != "count"))
            return error("an ID-2 takes: set stop 0|1, set count N");
        return set_id2(model, words[1], words[2]);
    }
    const auto module = parse_module_address(words[1]);
    if (!module) return error(module.error().message);
    std::vector<std::uint16_t> raw;
    for (std::size_t i = 2; i < words.size(); ++i) {
        const auto value = parse_unsigned(words[i], 0xFFFF);
        if (!value) return error(fmt::format("'{}' is not a value 0-65535", words[i]));
        raw.push_back(static_cast<std::uint16_t>(*value));
    }
    return from(model.set_values(*module, raw));
}

ControlReply get(DeviceModel& model, std::string_view target) {
    if (model.protocol() == Protocol::id2) {
        if (target == "stop") return ok(fmt::format("{}\n", model.stop_input() ? 1 : 0));
        if (target == "count") return ok(fmt::format("{}\n", model.counter()));
        return error("an ID-2 takes: get stop, get count");
    }
    const auto module = parse_module_address(target);
    if (!module) return error(module.error().message);
    const auto values = model.values(*module);
    if (!values) return error(values.error().message);
    return ok(fmt::format("{}\n", fmt::join(*values, " ")));
}

ControlReply fault(DeviceModel& model, const std::vector<std::string_view>& words) {
    if (words.size() < 3) return error("fault needs a target and a kind");
    const auto kind = fault_kind_from_name(words[2]);
    if (!kind)
        return error(
            fmt::format("unknown fault '{}': none silent error-ack garbage short long "
                        "delay",
                        words[2]));
    Fault spec{*kind, 1.0, {}};
    for (std::size_t i = 3; i < words.size(); ++i) {
        // A duration has a unit ("150ms"); a bare number is a probability.
        if (std::isalpha(static_cast<unsigned char>(words[i].back()))) {
            const auto delay = parse_duration(words[i]);
            if (!delay) return error(delay.error().message);
            spec.delay = *delay;
            continue;
        }
        double probability = -1;
        const auto [end, ec] =
            std::from_chars(words[i].data(), words[i].data() + words[i].size(), probability);
        if (ec != std::errc{} || end != words[i].data() + words[i].size() || probability < 0 ||
            probability > 1)
            return error(fmt::format("'{}' is neither a probability 0-1 nor a duration", words[i]));
        spec.probability = probability;
    }
    if (spec.kind == FaultKind::delay && spec.delay.count() == 0)
        return error("a delay fault needs a duration, e.g. fault dim16:0 delay 150ms");
    if (words[1] == "all" || words[1] == "device") {
        model.set_fault_all(spec);
        return ok();
    }
    if (model.protocol() == Protocol::id2) {
        const auto command = words[1].size() == 1 ? id2::parse_request(words[1][0]) : std::nullopt;
        if (!command) return error("an ID-2 takes: fault device|I|C|R KIND ...");
        return from(model.set_id2_fault(*command, spec));
    }
    const auto module = parse_module_address(words[1]);
    if (!module) return error(module.error().message);
    return from(model.set_fault(*module, spec));
}

ControlReply log(DeviceModel& model, const std::vector<std::string_view>& words) {
    if (words.size() == 2 && words[1] == "clear") {
        model.clear_log();
        return ok();
    }
    // "take" reads and clears in one command: between a "log" and a "log clear" the master's
    // next transactions would be lost, and a long run must drain the log before it is full.
    const bool take = words.size() == 2 && words[1] == "take";
    if (words.size() != 1 && !take) return error("log takes nothing, 'clear' or 'take'");
    std::string text;
    for (const auto& entry : model.log())
        text += fmt::format("{} {} {}\n", entry.at.count(), printable(entry.request),
                            entry.answer.empty() ? "-" : printable(entry.answer));
    const auto count = model.log().size();
    if (take) model.clear_log();
    return {text + fmt::format("ok {}\n", count), std::nullopt};
}

ControlReply module_command(DeviceModel& model, const std::vector<std::string_view>& words) {
    if (words.size() != 2) return error(fmt::format("{} takes one module", words[0]));
    const auto module = parse_module_address(words[1]);
    if (!module) return error(module.error().message);
    return from(words[0] == "add" ? model.add(*module) : model.remove(*module));
}

}  // namespace

ControlReply execute(DeviceModel& model, std::string_view line) {
    const auto words = split(line);
    if (words.empty()) return error("empty command: try help");
    const auto verb = words[0];
    if (verb == "help") return ok(std::string(control_help));
    if (verb == "modules") {
        std::string text;
        for (const auto module : model.modules())
            text += fmt::format("{}:{}\n", name(module.type), module.number);
        return ok(text);
    }
    if (verb == "add" || verb == "remove") return module_command(model, words);
    if (verb == "set") return set(model, words);
    if (verb == "get") {
        if (words.size() != 2) return error("get takes one target");
        return get(model, words[1]);
    }
    if (verb == "pulse") {
        const auto count = words.size() == 2 ? parse_unsigned(words[1], 65535) : std::nullopt;
        if (!count) return error("pulse takes a count 0-65535");
        model.pulse(static_cast<unsigned>(*count));
        return ok();
    }
    if (verb == "fault") return fault(model, words);
    if (verb == "log") return log(model, words);
    if (verb == "faults") {
        std::string text;
        for (std::size_t kind = 1; kind < model.injected().size(); ++kind)
            text += fmt::format("{}{} {}", kind == 1 ? "" : " ", name(static_cast<FaultKind>(kind)),
                                model.injected()[kind]);
        return ok(text + "\n");
    }
    if (verb == "unplug") {
        PortAction action{PortAction::Kind::unplug, std::nullopt};
        if (words.size() == 2) {
            const auto after = parse_duration(words[1]);
            if (!after) return error(after.error().message);
            action.after = *after;
        } else if (words.size() != 1) {
            return error("unplug takes an optional duration");
        }
        return {"ok\n", action};
    }
    if (verb == "replug") return {"ok\n", PortAction{PortAction::Kind::replug, std::nullopt}};
    if (verb == "chatter") {
        if (words.size() != 2) return error("chatter takes an interval, e.g. chatter 5ms, or off");
        if (words[1] == "off") return {"ok\n", PortAction{PortAction::Kind::chatter, std::nullopt}};
        const auto every = parse_duration(words[1]);
        if (!every || every->count() <= 0)
            return error(fmt::format("'{}' is not an interval such as 5ms, or off", words[1]));
        return {"ok\n", PortAction{PortAction::Kind::chatter, *every}};
    }
    return error(fmt::format("unknown command '{}': try help", verb));
}

}  // namespace ioport::sim
