#include "config/loader.hpp"

#include <cctype>

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 10> link_keys{
    "name",    "protocol", "device",  "baud",     "unit_id",
    "timeout", "retries",  "modules", "identity", "max_pending_writes"};
constexpr std::array<std::string_view, 10> module_keys{"type",   "number",  "poll", "initial",
                                                       "safe",   "refresh", "name", "channels",
                                                       "inputs", "outputs"};
// `identity:` keys by object id; MajorMinorRevision (0x02) is the version and not a key.
constexpr std::array<std::string_view, modbus::device_object_count> identity_keys{
    "vendor_name",  "product_code", "major_minor_revision", "vendor_url",
    "product_name", "model_name",   "user_application_name"};
constexpr std::size_t max_identity_length = 64;

constexpr std::string_view module_needed =
    "an ioport link needs at least one module, e.g. modules: [{ type: dim16, number: 0 }]";
// A refresh is one serial transaction per output module; faster than this it would crowd out
// the poll reads.
constexpr microseconds min_refresh = 10ms;

constexpr std::array<std::pair<std::string_view, Protocol>, 2> protocols{
    {{"ioport", Protocol::ioport}, {"id2", Protocol::id2}}};

Parsed<std::string> non_empty(const YAML::Node& value) {
    if (value.Scalar().empty()) return Unexpected(std::string("must not be empty"));
    return value.Scalar();
}

Parsed<ModuleType> module_type(const YAML::Node& value) {
    if (const auto type = module_type_from_name(value.Scalar())) return *type;
    return Unexpected(
        fmt::format("'{}' is not a module type: use dim16, dom16, acm3p, acm3c, "
                    "lim16, rgbdm, dccim, dcvim or mux8m",
                    value.Scalar()));
}

std::string output_value_help(ModuleType type) {
    switch (type) {
        case ModuleType::rgbdm:
            return "use a colour 0-7 or off, red, green, blue, cyan, magenta, yellow, white";
        case ModuleType::mux8m:
            return "use (pos << 8) | neg with pos and neg 0-7, e.g. 0x0102; 0x0707 = all "
                   "disconnected";
        case ModuleType::dom16:
            return "use the 16 outputs as one word 0..0xFFFF (bit k = output k), e.g. 0x00FF";
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;  // input modules take no initial value
    }
    return "";
}

// `initial` and `safe`: the module's holding register value; an rgbdm also takes a colour name.
auto output_value(ModuleType type, std::string_view key) {
    return [=](const YAML::Node& value) -> Parsed<std::uint16_t> {
        const std::string& text = value.Scalar();
        if (type == ModuleType::rgbdm)
            if (const auto colour = colour_from_name(text))
                return static_cast<std::uint16_t>(*colour);
        const auto number = parse_unsigned(text, 0xFFFF);
        if (number && quoted(value))
            return Unexpected(fmt::format(
                "\"{}\" is quoted, so it is text: write the number without quotes", text));
        if (!number)
            return Unexpected(fmt::format("'{}' is not {} {} value for {}: {}", text,
                                          key == "initial" ? "an" : "a", key, name(type),
                                          output_value_help(type)));
        const auto register_value = static_cast<std::uint16_t>(*number);
        if (auto ok = validate_output_value(type, register_value); !ok)
            return Unexpected(std::move(ok).error().message);
        return register_value;
    };
}

auto baud(std::optional<Protocol> protocol) {
    return [=](const YAML::Node& value) -> Parsed<int> {
        auto rate = integer(1, std::numeric_limits<int>::max())(value);
        if (!rate || !protocol) return rate;
        if (*protocol == Protocol::id2 && *rate != 9600)
            return Unexpected(fmt::format("{} is not allowed for protocol id2: use 9600", *rate));
        if (*protocol == Protocol::ioport && *rate != 38400 && *rate != 115200)
            return Unexpected(
                fmt::format("{} is not allowed for protocol ioport: use 38400 or 115200", *rate));
        return rate;
    };
}

}  // namespace

void Loader::read_links(const Entry& entry, std::vector<LinkConfig>& links) {
    if (!entry.value.IsSequence() || entry.value.size() == 0) {
        add(entry.line, "links",
            fmt::format("expected a list of at least one link, found {}",
                        entry.value.IsSequence() ? "an empty list" : kind(entry.value)));
        return;
    }
    std::size_t index = 0;
    for (const auto& node : entry.value)
        read_link(node, index++, links);
}

void Loader::read_link(const YAML::Node& node, std::size_t index, std::vector<LinkConfig>& links) {
    const std::string path = fmt::format("links[{}]", index);
    if (!node.IsMap()) {
        add(line_of(node), path,
            fmt::format("expected a mapping with name, protocol and device, found {}", kind(node)));
        return;
    }
    const Fields f = fields(node, path, link_keys);
    LinkConfig link;
    link.line = f.line;
    const LinkOutcome outcome = read_link_settings(f, index, link);
    read_modules(f, outcome.protocol, link);
    read_identity(f, link);
    check_unique(f, link, outcome.unit_id_valid);
    links.push_back(std::move(link));
}

Loader::LinkOutcome Loader::read_link_settings(const Fields& f, std::size_t index,
                                               LinkConfig& link) {
    LinkOutcome outcome;
    require(f, "name", "every link needs a name, e.g. name: hub0");
    read(f, "name", "a name such as hub0", link.name, non_empty);
    require(f, "protocol", "use protocol: ioport (hub8u/hub8r) or protocol: id2");
    read(f, "protocol", "ioport or id2", outcome.protocol, choice<Protocol>(protocols));
    // Defaults that depend on the protocol, before the keys that may override them.
    const bool id2 = outcome.protocol == Protocol::id2;
    link.protocol = outcome.protocol.value_or(Protocol::ioport);
    link.baud = id2 ? 9600 : 115200;
    link.timeout = id2 ? microseconds{200ms} : microseconds{100ms};
    link.unit_id = static_cast<int>(index) + 1;
    require(f, "device", "the serial port, e.g. device: /dev/ttyUSB0");
    read(f, "device", "a path such as /dev/ttyUSB0", link.device, non_empty);
    read(f, "baud", "a baud rate", link.baud, baud(outcome.protocol));
    if (f.find("unit_id") == nullptr && link.unit_id > max_unit_id) {
        add(f.line, f.key("unit_id"),
            fmt::format("missing: the default {} (1 + the link's index) is over {}: set unit_id",
                        link.unit_id, max_unit_id));
        outcome.unit_id_valid = false;
    }
    if (f.find("unit_id") != nullptr)
        outcome.unit_id_valid =
            read(f, "unit_id", "a unit id 1..247", link.unit_id, integer(1, max_unit_id));
    read(f, "timeout", "a duration such as 100ms", link.timeout,
         duration(microseconds{1ms}, microseconds{10s}));
    read(f, "retries", "a number 0..10", link.retries, integer(0, 10));
    read(f, "max_pending_writes", "a number 1..1024", link.max_pending_writes, integer(1, 1024));
    return outcome;
}

void Loader::read_modules(const Fields& f, std::optional<Protocol> protocol, LinkConfig& link) {
    const Entry* entry = f.find("modules");
    const std::string key = f.key("modules");
    if (protocol == Protocol::id2) {
        if (entry != nullptr)
            add(entry->line, key,
                "an id2 link takes no modules (its Modbus map is fixed): remove "
                "the key");
        return;
    }
    if (entry == nullptr) {
        if (protocol) require(f, "modules", module_needed);
        return;
    }
    if (!entry->value.IsSequence() || entry->value.size() == 0) {
        add(entry->line, key,
            fmt::format("expected a list of at least one module, found {}: {}",
                        entry->value.IsSequence() ? "an empty list" : kind(entry->value),
                        module_needed));
        return;
    }
    std::map<int, int> first_line;  // slot → line: a duplicate is reported at its second use
    // Module names as resolved, so that a name equal to another module's default is caught too.
    std::map<std::string, std::size_t, std::less<>> names;  // → index in link.modules
    std::size_t index = 0;
    for (const auto& node : entry->value) {
        const std::string path = fmt::format("{}[{}]", key, index++);
        const auto module = read_module(node, path);
        if (!module) continue;
        const auto [first, fresh] = first_line.try_emplace(slot(module->address), module->line);
        if (!fresh) {
            add(module->line, path,
                fmt::format("{} is already configured on this link at line {}",
                            to_string(module->address), first->second));
            continue;
        }
        const auto [named, unique] = names.try_emplace(module->tags.name, link.modules.size());
        if (!unique) {
            const ModuleConfig& owner = link.modules[named->second];
            add(module->line, path + ".name",
                fmt::format("module name '{}' is already used on this link by {} at line {}: "
                            "names must be unique per link",
                            printable(module->tags.name, 80), to_string(owner.address),
                            owner.line));
        }
        link.modules.push_back(*module);
    }
}

std::optional<ModuleConfig> Loader::read_module(const YAML::Node& node, const std::string& path) {
    if (!node.IsMap()) {
        add(line_of(node), path,
            fmt::format("expected a mapping such as {{ type: dim16, number: 0 }}, found {}",
                        kind(node)));
        return std::nullopt;
    }
    const Fields f = fields(node, path, module_keys);
    require(f, "type", "the module type, e.g. type: dim16");
    require(f, "number", "the module's address switch 0..7, e.g. number: 0");
    std::optional<ModuleType> type;
    std::optional<std::uint8_t> number;
    read(f, "type", "a module type such as dim16", type, module_type);
    read(f, "number", "a number 0..7", number, integer<std::uint8_t>(0, 7));
    if (!type) return std::nullopt;  // which keys belong depends on the type
    ModuleConfig module{.address = {*type, number.value_or(0)}, .line = f.line, .tags = {}};
    read_module_role(f, module);
    read_tags(f, module);
    if (!number) return std::nullopt;
    return module;
}

void Loader::read_module_role(const Fields& f, ModuleConfig& module) {
    const ModuleType type = module.address.type;
    const auto misplaced = [&](std::string_view key, std::string_view why) {
        if (const Entry* entry = f.find(key)) add(entry->line, f.key(key), std::string(why));
    };
    if (is_output(type)) {
        misplaced("poll", fmt::format("poll is for input modules only: {} is an output module, "
                                      "its state is re-sent every refresh",
                                      name(type)));
        read(f, "initial", "a register value", module.initial, output_value(type, "initial"));
        module.safe = module.initial;
        read(f, "safe", "a register value", module.safe, output_value(type, "safe"));
        read(f, "refresh", "a duration such as 1s", module.refresh, duration(min_refresh));
        return;
    }
    for (const std::string_view key : {"initial", "safe", "refresh"})
        misplaced(key, fmt::format("{} is for output modules only (dom16, rgbdm, mux8m): {} is "
                                   "an input module",
                                   key, name(type)));
    read(f, "poll", "a duration such as 200ms, or 0 for every cycle", module.poll,
         duration(microseconds{0}));
}

void Loader::read_identity(const Fields& link_fields, LinkConfig& link) {
    const Entry* entry = link_fields.find("identity");
    if (entry == nullptr || entry->value.IsNull()) return;
    const auto f = mapping(*entry, link_fields.key("identity"), identity_keys,
                           "{ model_name: hub8u, user_application_name: press line 2 }");
    if (!f) return;
    const auto text = [](const YAML::Node& value) -> Parsed<std::string> {
        const std::string& s = value.Scalar();
        if (s.empty() || s.size() > max_identity_length)
            return Unexpected(fmt::format("'{}' has {} characters: use 1 to {}", s, s.size(),
                                          max_identity_length));
        if (!std::ranges::all_of(s, [](char c) { return c >= 0x20 && c <= 0x7E; }))
            return Unexpected(fmt::format(
                "'{}' has a character that is not printable ASCII: use letters, digits, spaces "
                "and punctuation",
                printable(s)));
        return s;
    };
    for (std::size_t id = 0; id < identity_keys.size(); ++id) {
        if (id == static_cast<std::size_t>(modbus::DeviceObject::major_minor_revision)) {
            if (const Entry* revision = f->find(identity_keys[id]))
                add(revision->line, f->key(identity_keys[id]),
                    "MajorMinorRevision is the ioportd version and cannot be set: remove the key");
            continue;
        }
        read(*f, identity_keys[id], "printable text", link.identity[id], text);
    }
}

void Loader::check_unique(const Fields& f, const LinkConfig& link, bool unit_id_valid) {
    const FirstUse me{link.name.empty() ? f.path : fmt::format("link '{}'", link.name), f.line};
    if (!link.name.empty()) {
        // Unique ignoring case: the name is part of Sparkplug metric names and device ids, and
        // hosts may not tell hub0 from Hub0 (Sparkplug 3.0, case-sensitivity-metric-names).
        auto folded = link.name;
        std::ranges::transform(folded, folded.begin(),
                               [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
        const auto [first, fresh] = names_.try_emplace(folded, me);
        if (!fresh)
            add(f.line_of("name"), f.key("name"),
                fmt::format("link name '{}' is already used at line {}: names must be unique, "
                            "and unique ignoring case",
                            link.name, first->second.line));
    }
    if (unit_id_valid) {
        const auto [first, fresh] = unit_ids_.try_emplace(link.unit_id, me);
        if (!fresh)
            add(f.line_of("unit_id"), f.key("unit_id"),
                fmt::format("unit id {}{} is already used by {} (line {}): each link needs its "
                            "own",
                            link.unit_id,
                            f.find("unit_id") ? "" : " (the default: 1 + the link's index)",
                            first->second.link, first->second.line));
    }
    if (!link.device.empty()) {
        // Two spellings of one port (a by-id symlink and /dev/ttyUSB0) are one port.
        const std::string resolved = resolve_(link.device);
        const auto [first, fresh] = devices_.try_emplace(resolved, me);
        if (!fresh)
            add(f.line_of("device"), f.key("device"),
                fmt::format("device {} is already used by {} (line {}){}", link.device,
                            first->second.link, first->second.line,
                            resolved == link.device ? "" : fmt::format(": both are {}", resolved)));
    }
}

}  // namespace ioport::config::detail
