#include "config/loader.hpp"

#include <sstream>

#include <yaml-cpp/eventhandler.h>

#include "config/tls_files.hpp"

namespace ioport::config::detail {
namespace {

constexpr std::array<std::string_view, 7> top_keys{"modbus", "http",        "mqtt",     "mqtt_json",
                                                   "links",  "on_shutdown", "log_level"};

constexpr std::array<std::pair<std::string_view, OnShutdown>, 2> on_shutdown_choices{
    {{"keep", OnShutdown::keep}, {"initial", OnShutdown::initial}}};

Parsed<LogLevel> named_log_level(const YAML::Node& value) {
    if (const auto level = log_level_from_name(value.Scalar())) return *level;
    return Unexpected(
        fmt::format("'{}' is not allowed: use trace or debug or info or warn or "
                    "error or critical or off",
                    value.Scalar()));
}

}  // namespace

Fields Loader::fields(const YAML::Node& map, std::string path, Keys allowed) {
    Fields result{std::move(path), line_of(map), {}};
    for (const auto& pair : map) {
        const int line = line_of(pair.first);
        const std::string name = pair.first.IsScalar() ? pair.first.Scalar() : "";
        const std::string key = result.key(name);
        if (!pair.first.IsScalar())
            add(line, result.path, fmt::format("a key must be a name, found {}", kind(pair.first)));
        else if (std::ranges::find(allowed, name) == allowed.end())
            add(line, key,
                fmt::format("unknown key: allowed here are {}", fmt::join(allowed, ", ")));
        else if (const Entry* first = result.find(name))
            add(line, key, fmt::format("duplicate key: already given at line {}", first->line));
        else
            result.entries.emplace_back(name, Entry{pair.second, line});
    }
    return result;
}

std::optional<Fields> Loader::mapping(const Entry& entry, std::string path, Keys allowed,
                                      std::string_view example) {
    if (entry.value.IsMap()) return fields(entry.value, std::move(path), allowed);
    add(entry.line, std::move(path),
        fmt::format("expected a mapping such as {}, found {}", example, kind(entry.value)));
    return std::nullopt;
}

void Loader::require(const Fields& fields, std::string_view name, std::string_view help) {
    if (fields.find(name) == nullptr)
        add(fields.line, fields.key(name), fmt::format("missing: {}", help));
}

void Loader::read_allow(const Fields& f, std::vector<Network>& allow) {
    read_list(f, "allow", "a list of networks such as [\"10.0.0.0/8\", \"127.0.0.1\"]",
              "a network such as 10.0.0.0/8", parse_network, allow);
}

void Loader::read_root(const YAML::Node& root, GatewayConfig& config) {
    if (root.IsNull()) {
        add(0, "links", "the file is empty: it needs at least one link under links");
        return;
    }
    if (!root.IsMap()) {
        add(line_of(root), "", "expected a mapping with the keys modbus and links");
        return;
    }
    const Fields top = fields(root, "", top_keys);
    if (const Entry* modbus = top.find("modbus")) read_modbus(*modbus, config.modbus);
    if (const Entry* http = top.find("http")) read_http(*http, config.http);
    require(top, "links", "the gateway needs at least one link");
    if (const Entry* links = top.find("links")) read_links(*links, config.links);
    if (const Entry* mqtt = top.find("mqtt")) read_mqtt(*mqtt, config.mqtt);
    if (config.mqtt) check_sparkplug_ids(config);
    if (const Entry* json = top.find("mqtt_json")) read_mqtt_json(*json, config.mqtt_json);
    if (config.mqtt_json) check_topic_levels(config);
    check_client_ids(config);
    check_role_units(config);
    read(top, "on_shutdown", "keep or initial", config.on_shutdown,
         choice<OnShutdown>(on_shutdown_choices));
    read(top, "log_level", "a log level", config.log_level, named_log_level);
}

}  // namespace ioport::config::detail

namespace ioport::config {
namespace {

// --- Documents ------------------------------------------------------------------------------

// yaml-cpp 0.7's LoadAll never returns on some invalid text, a ',' outside [ ] or { } for one
// (jbeder/yaml-cpp#1040, fixed upstream after 0.8): its parser stops consuming the text and
// yields the same empty document over and over, and LoadAll keeps each one until memory runs
// out. So the documents are counted here, a bounded number of them, and one that starts where the
// previous one did is a syntax error.
class DocumentStarts : public YAML::EventHandler {
  public:
    struct Document {
        YAML::Mark start;
        std::optional<YAML::Mark> root;  // of its root node, where LoadAll's Node has its mark
    };
    std::vector<Document> documents;

    void OnDocumentStart(const YAML::Mark& mark) override { documents.push_back({mark, {}}); }
    void OnDocumentEnd() override {}
    void OnNull(const YAML::Mark& mark, YAML::anchor_t) override { node(mark); }
    void OnAlias(const YAML::Mark& mark, YAML::anchor_t) override { node(mark); }
    void OnScalar(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                  const std::string&) override {
        node(mark);
    }
    void OnSequenceStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                         YAML::EmitterStyle::value) override {
        node(mark);
    }
    void OnSequenceEnd() override {}
    void OnMapStart(const YAML::Mark& mark, const std::string&, YAML::anchor_t,
                    YAML::EmitterStyle::value) override {
        node(mark);
    }
    void OnMapEnd() override {}

  private:
    void node(const YAML::Mark& mark) {
        if (!documents.empty() && !documents.back().root) documents.back().root = mark;
    }
};

struct Documents {
    std::optional<YAML::Mark> second;    // the root of a second document
    std::optional<YAML::Mark> stuck_at;  // where the parser stopped making progress
};

Documents scan_documents(const std::string& text) {
    std::istringstream stream(text);
    YAML::Parser parser(stream);
    DocumentStarts starts;
    auto& documents = starts.documents;
    // Three are enough to tell a second document from a parser stuck at the first or second.
    while (documents.size() < 3 && parser.HandleNextDocument(starts)) {
        const auto count = documents.size();
        if (count >= 2 && documents[count - 1].start.pos == documents[count - 2].start.pos)
            return {std::nullopt, documents[count - 1].start};
    }
    if (documents.size() < 2) return {};
    return {documents[1].root.value_or(documents[1].start), std::nullopt};
}

std::string stuck_message(const std::string& text, const YAML::Mark& mark) {
    const auto at = static_cast<std::size_t>(std::max(mark.pos, 0));
    if (at < text.size() && text[at] == ',')
        return fmt::format(
            "YAML syntax error at column {}: a ',' separates the items of a [ ] or {{ }} "
            "list, and there is none here",
            mark.column + 1);
    return fmt::format("YAML syntax error at column {}: no value can start here", mark.column + 1);
}

// The configuration grants rights too (roles, the files it names): read as read_protected_file
// reads them. Its messages begin with the path, which the configuration's error names already.
detail::Parsed<std::string> read_config_file(const std::string& path) {
    constexpr std::size_t max_config_size = std::size_t{4} * 1024 * 1024;
    auto text = read_protected_file(path, Secrecy::public_file, max_config_size);
    if (text) return text;
    std::string message = std::move(text).error();
    if (message.starts_with(path)) message.erase(0, path.size());
    if (message.starts_with(": ")) return Unexpected("cannot read the file" + message);
    if (message.starts_with(' ')) message.erase(0, 1);
    return Unexpected(std::move(message));
}

}  // namespace

ConfigResult parse_config(std::string_view yaml, const std::string& file,
                          const DeviceResolver& resolve) {
    detail::Loader loader(file, resolve);
    const std::string text(yaml);
    // yaml-cpp reports syntax errors by throwing; from here on they are values.
    try {
        const auto documents = scan_documents(text);
        if (documents.stuck_at) {
            const auto& mark = *documents.stuck_at;
            return Unexpected(
                std::vector{ConfigError{file, mark.line + 1, "", stuck_message(text, mark)}});
        }
        if (documents.second)
            loader.add(documents.second->line + 1, "",
                       "one YAML document only: remove the second '---' and what follows");
        return loader.load(YAML::Load(text));  // the first document, or null for none
    } catch (const YAML::Exception& e) {
        return Unexpected(std::vector{
            ConfigError{file, e.mark.line + 1, "", fmt::format("YAML syntax error: {}", e.msg)}});
    }
}

ConfigResult load_config(const std::filesystem::path& path, const DeviceResolver& resolve) {
    auto text = read_config_file(path.string());
    if (!text)
        return Unexpected(std::vector{ConfigError{path.string(), 0, "", std::move(text).error()}});
    return parse_config(*text, path.string(), resolve);
}

}  // namespace ioport::config
