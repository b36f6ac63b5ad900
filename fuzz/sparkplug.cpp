// Fuzz target: what the Sparkplug edge node takes from the broker (protocol/sparkplug.hpp):
// NCMD/DCMD payloads, topics and STATE messages, all of which any client of the broker can send.
//
// Input: byte 0 picks the device a DCMD goes to (module type 0..8 as ModuleType, 9 and above the
// ID-2); the rest is the payload, and also read as a topic and as a STATE message.
//
// Invariants, from gateway.md §5.5 and Sparkplug 3.0 rather than from the code under test:
// - decode either fails with `malformed` or gives a payload that encodes and decodes again;
// - a parsed topic is the topic that topic()/state_topic() builds from its parts;
// - a planned DCMD is a write the gateway could send: each change's bits lie within its mask,
//   merged into any state it gives a value the module accepts (validate_output_value), and the
//   change is to the device the command was for; a reset only for the ID-2;
// - a refusal names the metric;
// - a command to a device is decoded only when it names no more metrics than the device has
//   writable ones and fits max_command_bytes of them; anything larger is refused whole, before
//   decoding, as invalid_argument (gateway.md §5.5); the metrics counted without decoding are the
//   metrics decode finds;
// - templates (gateway.md §7.2): an instance's members count one by one, and the writes counted
//   before decoding are never fewer than those decoded (the bound is checked on the bytes); the
//   writes of a command metric (command_writes) are flat metrics, each planned like any other;
//   flattening a decoded payload gives its flat metrics and every instance's members.
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "fuzz/fuzz.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::fuzz {
namespace {

void check_topic(std::string_view text) {
    const auto topic = sparkplug::parse_topic(text);
    if (!topic) return;
    const auto built =
        topic->type == sparkplug::MessageType::state
            ? sparkplug::state_topic(topic->node)
            : sparkplug::topic(topic->group, topic->type, topic->node, topic->device);
    check(built == text, "a parsed topic is the one its parts build");
}

void check_command(std::optional<ModuleAddress> module, const sparkplug::Metric& metric) {
    const auto plan = sparkplug::plan_command(module, metric.name, metric.datatype, metric.value);
    if (!plan) {
        check(plan.error().code == Errc::invalid_argument, "a refused command is invalid_argument");
        check(plan.error().message.find(metric.name) != std::string::npos,
              "a refusal names the metric");
        return;
    }
    check(!plan->reset_counter || !module, "only the ID-2 resets a counter");
    for (const auto& change : plan->changes) {
        check(module && change.module == *module, "a change is to the commanded module");
        check((change.value & ~change.mask) == 0, "a change's bits lie within its mask");
        for (const std::uint16_t desired : {std::uint16_t{0}, std::uint16_t{0x0707}})
            check(validate_output_value(change.module.type, gateway::merged(desired, change))
                      .has_value(),
                  "a planned command merges into a value the module accepts");
    }
}

// A DCMD metric to a device with templates: its writes, each a flat metric planned as one.
void check_writes(std::optional<ModuleAddress> module, const sparkplug::Metric& metric) {
    const auto type = module ? std::optional(module->type) : std::nullopt;
    const auto writes = sparkplug::command_writes(type, metric, true);
    if (!writes) {
        check(writes.error().code == Errc::invalid_argument,
              "a refused instance is invalid_argument");
        return;
    }
    for (const auto& write : *writes) {
        check(!write.template_value, "a write is a flat metric");
        check_command(module, write);
    }
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace ioport;
    if (size == 0) return 0;
    const std::span<const std::uint8_t> bytes(data + 1, size - 1);
    const std::string_view text(reinterpret_cast<const char*>(bytes.data()), bytes.size());
    fuzz::check_topic(text);
    if (const auto state = sparkplug::parse_state(text)) {
        const auto again =
            sparkplug::parse_state(sparkplug::state_json(state->online, state->timestamp));
        fuzz::check(again && *again == *state, "a STATE reads back as state_json() writes it");
    }

    std::optional<ModuleAddress> module;
    if (data[0] < module_type_count) module = ModuleAddress{static_cast<ModuleType>(data[0]), 0};
    const auto writable =
        sparkplug::writable_metrics(module ? std::optional(module->type) : std::nullopt);
    const auto counted = sparkplug::count_metrics(bytes);
    const auto writes = sparkplug::count_command_metrics(bytes);
    const auto command = sparkplug::decode_command(bytes, writable);
    if (command) {
        fuzz::check(command->metrics.size() <= writable,
                    "a command names no more metrics than the device has writable ones");
        fuzz::check(sparkplug::command_metrics(command->metrics) <= writable,
                    "a command's instances hold no more members than the device writes");
        fuzz::check(bytes.size() <= sparkplug::max_command_bytes(writable),
                    "a command decoded is within the bytes of its device");
        fuzz::check(counted && *counted == command->metrics.size(),
                    "the metrics counted are the metrics decoded");
        fuzz::check(writes && *writes >= sparkplug::command_metrics(command->metrics),
                    "the writes counted before decoding are never fewer than those decoded");
        for (const auto& metric : command->metrics)
            fuzz::check_writes(module, metric);
    } else if (command.error().code == Errc::invalid_argument) {
        fuzz::check(
            bytes.size() > sparkplug::max_command_bytes(writable) || (writes && *writes > writable),
            "a command refused whole is too long or names too many metrics");
    } else {
        fuzz::check(command.error().code == Errc::malformed, "a command that fails is malformed");
    }

    const auto payload = sparkplug::decode(bytes);
    if (!payload) {
        fuzz::check(payload.error().code == Errc::malformed, "a payload that fails is malformed");
        return 0;
    }
    if (counted)
        fuzz::check(*counted == payload->metrics.size(),
                    "the metrics counted are the metrics decoded");
    fuzz::check(sparkplug::decode(sparkplug::encode(*payload)).has_value(),
                "a decoded payload encodes to one that decodes");
    std::size_t leaves = 0;
    for (const auto& metric : payload->metrics)
        leaves += metric.template_value ? metric.template_value->members.size() : 1;
    fuzz::check(sparkplug::to_flat(payload->metrics).size() == leaves,
                "flattening gives every flat metric and every instance's members");
    for (const auto& metric : payload->metrics)
        fuzz::check_command(module, metric);
    return 0;
}
