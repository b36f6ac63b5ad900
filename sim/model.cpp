#include "sim/model.hpp"

#include <fmt/format.h>

#include "protocol/id2.hpp"

namespace ioport::sim {
namespace {

constexpr std::array<std::string_view, 7> fault_names{"none",  "silent", "error-ack", "garbage",
                                                      "short", "long",   "delay"};

std::size_t fault_index(id2::Command command) {
    switch (command) {
        case id2::Command::stop_input:
            return 0;
        case id2::Command::count:
            return 1;
        case id2::Command::reset:
            return 2;
    }
    return 0;
}

}  // namespace

std::string_view name(FaultKind kind) {
    return fault_names[static_cast<std::size_t>(kind)];
}

std::optional<FaultKind> fault_kind_from_name(std::string_view text) {
    for (std::size_t i = 0; i < fault_names.size(); ++i)
        if (fault_names[i] == text) return static_cast<FaultKind>(i);
    return std::nullopt;
}

DeviceModel::DeviceModel(Protocol protocol, std::uint64_t seed)
    : protocol_(protocol), framer_(cr, max_request_length), rng_(seed) {}

std::vector<Answer> DeviceModel::receive(std::string_view bytes, std::chrono::microseconds now) {
    std::vector<Answer> answers;
    const auto keep = [&](std::string request, std::optional<Answer> answer) {
        record(now, std::move(request), answer);
        if (answer) answers.push_back(std::move(*answer));
    };
    if (protocol_ == Protocol::id2) {
        for (const char byte : bytes)
            keep(std::string(1, byte), answer_id2(byte));
        return answers;
    }
    framer_.feed(bytes, [&](const Frame& frame) {
        // A line of noise longer than any request is no request: a module stays silent.
        keep(std::string(frame.bytes), frame.overflowed ? std::nullopt : answer_hub(frame.bytes));
    });
    return answers;
}

Result<ModuleState*> DeviceModel::present(ModuleAddress module) {
    if (protocol_ != Protocol::ioport)
        return fail(Errc::invalid_argument, "this simulator is an ID-2, it has no modules");
    auto& state = modules_[static_cast<std::size_t>(slot(module))];
    if (!state.present)
        return fail(Errc::invalid_argument,
                    fmt::format("{} is not on this hub (add it first)", to_string(module)));
    return &state;
}

Result<> DeviceModel::add(ModuleAddress module) {
    if (protocol_ != Protocol::ioport)
        return fail(Errc::invalid_argument, "this simulator is an ID-2, it has no modules");
    modules_[static_cast<std::size_t>(slot(module))].present = true;
    return {};
}

Result<> DeviceModel::remove(ModuleAddress module) {
    auto state = present(module);
    if (!state) return Unexpected(state.error());
    **state = ModuleState{};
    return {};
}

std::vector<ModuleAddress> DeviceModel::modules() const {
    std::vector<ModuleAddress> list;
    for (int s = 0; s < slot_count; ++s)
        if (modules_[static_cast<std::size_t>(s)].present) list.push_back(module_at_slot(s));
    return list;
}

Result<> DeviceModel::set_values(ModuleAddress module, std::span<const std::uint16_t> raw) {
    auto state = present(module);
    if (!state) return Unexpected(state.error());
    // An output's state is normally the master's to set; setting it here stands for a module
    // that lost power or was reset behind the master's back.
    const auto words = is_output(module.type) ? std::size_t{1}
                                              : static_cast<std::size_t>(reply_words(module.type));
    if (raw.size() != words)
        return fail(Errc::invalid_argument, fmt::format("{} takes {} value(s), got {}",
                                                        to_string(module), words, raw.size()));
    if (is_output(module.type)) {
        if (auto valid = validate_output_value(module.type, raw[0]); !valid)
            return Unexpected(valid.error());
    }
    std::copy(raw.begin(), raw.end(), (*state)->raw.begin());
    return {};
}

Result<std::vector<std::uint16_t>> DeviceModel::values(ModuleAddress module) const {
    if (protocol_ != Protocol::ioport || !modules_[static_cast<std::size_t>(slot(module))].present)
        return fail(Errc::invalid_argument,
                    fmt::format("{} is not on this hub", to_string(module)));
    const auto& raw = modules_[static_cast<std::size_t>(slot(module))].raw;
    const auto words = is_output(module.type) ? 1 : reply_words(module.type);
    return std::vector<std::uint16_t>(raw.begin(), raw.begin() + words);
}

Result<> DeviceModel::set_fault(ModuleAddress module, Fault fault) {
    auto state = present(module);
    if (!state) return Unexpected(state.error());
    (*state)->fault = fault;
    return {};
}

void DeviceModel::set_fault_all(Fault fault) {
    id2_faults_.fill(fault);
    for (auto& state : modules_)
        if (state.present) state.fault = fault;
}

Result<> DeviceModel::set_id2_fault(id2::Command command, Fault fault) {
    if (protocol_ != Protocol::id2)
        return fail(Errc::invalid_argument, "this simulator is a hub: its faults are per module");
    id2_faults_[fault_index(command)] = fault;
    return {};
}

void DeviceModel::pulse(unsigned count) {
    counter_ = static_cast<std::uint16_t>(counter_ + count);
}

std::optional<Answer> DeviceModel::apply_fault(const Fault& fault, std::string good, bool& apply) {
    apply = true;
    if (fault.kind == FaultKind::none) return Answer{std::move(good), {}};
    if (fault.probability < 1.0 &&
        std::uniform_real_distribution<double>(0, 1)(rng_) >= fault.probability)
        return Answer{std::move(good), {}};
    const char terminator = good.back();
    apply = fault.kind == FaultKind::delay;
    ++injected_[static_cast<std::size_t>(fault.kind)];
    switch (fault.kind) {
        case FaultKind::silent:
            return std::nullopt;
        // From an input module "0" is simply a reply of the wrong length.
        case FaultKind::error_ack:
            return Answer{std::string{"0"} + terminator, {}};
        case FaultKind::garbage: {
            // Bytes no reply ever contains, so garbage can never decode as data by chance.
            static constexpr std::string_view noise = "GHJKLMNPQRSTUVWXYZ#*?!~\x01\x7F";
            std::string bytes;
            const auto length = std::uniform_int_distribution<std::size_t>(1, 20)(rng_);
            for (std::size_t i = 0; i < length; ++i)
                bytes +=
                    noise[std::uniform_int_distribution<std::size_t>(0, noise.size() - 1)(rng_)];
            return Answer{bytes + terminator, {}};
        }
        case FaultKind::short_reply:
            good.erase(good.size() - 2, 1);
            return Answer{std::move(good), {}};
        case FaultKind::long_reply:
            good.insert(good.end() - 1, '0');
            return Answer{std::move(good), {}};
        case FaultKind::delay:
            return Answer{std::move(good), fault.delay};
        case FaultKind::none:
            break;
    }
    return Answer{std::move(good), {}};
}

std::optional<Answer> DeviceModel::answer_hub(std::string_view frame) {
    const auto request = parse_request(frame);
    if (!request) return std::nullopt;  // strict like a module: a malformed request gets nothing
    auto& state = modules_[static_cast<std::size_t>(slot(request->module))];
    if (!state.present) return std::nullopt;
    const bool command = is_output(request->module.type);
    bool apply = false;
    auto answer = apply_fault(
        state.fault, command ? encode_ack(true) : encode_reading(request->module.type, state.raw),
        apply);
    if (command && apply) state.raw[0] = request->output_value;
    return answer;
}

std::optional<Answer> DeviceModel::answer_id2(char byte) {
    const auto command = id2::parse_request(byte);
    if (!command) return std::nullopt;
    std::string good;
    switch (*command) {
        case id2::Command::stop_input:
            good = id2::encode_stop_input(stop_input_);
            break;
        case id2::Command::count:
            good = id2::encode_count(counter_);
            break;
        case id2::Command::reset:
            good = id2::encode_reset_ok();
            break;
    }
    bool apply = false;
    auto answer = apply_fault(id2_faults_[fault_index(*command)], std::move(good), apply);
    if (*command == id2::Command::reset && apply) counter_ = 0;
    return answer;
}

void DeviceModel::record(std::chrono::microseconds now, std::string request,
                         const std::optional<Answer>& answer) {
    if (log_.size() >= log_capacity) log_.pop_front();
    log_.push_back({now, std::move(request), answer ? answer->bytes : std::string{}});
    if (!log_.back().answer.empty()) log_.back().answer.pop_back();  // drop the terminator
}

}  // namespace ioport::sim
