#include "protocol/json_reader.hpp"

#include <algorithm>

#include <nlohmann/json.hpp>

#include <fmt/format.h>

namespace ioport {
namespace {

// Of the parser's message, at most this much: it quotes what it read last, which may be a whole
// string or number of the peer's (tens of KiB), and the message is answered or logged.
constexpr std::size_t max_error_bytes = 160;

std::string bounded(std::string_view text) {
    if (text.size() <= max_error_bytes) return std::string(text);
    std::size_t end = 0;
    while (end < text.size()) {
        const auto length = std::max<std::size_t>(utf8_sequence(text.substr(end)), 1);
        if (end + length > max_error_bytes) break;
        end += length;
    }
    return fmt::format("{}...", text.substr(0, end));
}

}  // namespace

struct JsonObject::Document {
    nlohmann::json value;

    const nlohmann::json* member(std::string_view key) const {
        const auto found = value.find(key);
        return found == value.end() ? nullptr : &*found;
    }
};

JsonObject::JsonObject(std::shared_ptr<const Document> document) : document_(std::move(document)) {}

Result<JsonObject> JsonObject::parse(std::string_view text) {
    nlohmann::json value;
    try {
        value = nlohmann::json::parse(text);
    } catch (const nlohmann::json::exception& error) {
        // "[json.exception.parse_error.101] parse error at line 1, column 5: …": where reading
        // stopped and what was expected there, without the library's tag. Not only parse_error:
        // a number beyond a double's range (1e400) is out_of_range.406 "number overflow", which
        // took the daemon down from any client of the broker (a bridge request, a STATE).
        std::string_view what = error.what();
        if (const auto tag = what.find("] "); tag != std::string_view::npos)
            what.remove_prefix(tag + 2);
        return fail(Errc::malformed, fmt::format("not JSON: {}", bounded(what)));
    }
    if (!value.is_object()) return fail(Errc::malformed, "not a JSON object");
    return JsonObject(std::make_shared<const Document>(Document{std::move(value)}));
}

bool JsonObject::has(std::string_view key) const {
    return document_->member(key) != nullptr;
}

std::optional<bool> JsonObject::boolean(std::string_view key) const {
    const auto* member = document_->member(key);
    if (member == nullptr || !member->is_boolean()) return std::nullopt;
    return member->get<bool>();
}

std::optional<std::uint64_t> JsonObject::unsigned_integer(std::string_view key) const {
    const auto* member = document_->member(key);
    if (member == nullptr || !member->is_number_unsigned()) return std::nullopt;
    return member->get<std::uint64_t>();
}

std::optional<std::string> JsonObject::string(std::string_view key) const {
    const auto* member = document_->member(key);
    if (member == nullptr || !member->is_string()) return std::nullopt;
    return member->get<std::string>();
}

std::optional<std::string> JsonObject::scalar_text(std::string_view key) const {
    const auto* member = document_->member(key);
    if (member == nullptr) return std::nullopt;
    if (member->is_string()) return member->get<std::string>();
    if (member->is_number() || member->is_boolean()) return member->dump();
    return std::nullopt;
}

std::optional<std::string> JsonObject::json(std::string_view key) const {
    const auto* member = document_->member(key);
    if (member == nullptr) return std::nullopt;
    // `replace`: no string of a parsed document is invalid UTF-8, but a dump never throws.
    return member->dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::vector<std::string> JsonObject::keys() const {
    std::vector<std::string> names;
    for (const auto& [name, value] : document_->value.items())
        names.push_back(name);
    return names;
}

}  // namespace ioport
