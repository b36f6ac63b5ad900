// JSON that arrives from the network (a Sparkplug STATE, an HTTP write), read strictly: RFC 8259
// and nothing more (no comments, no trailing commas, no YAML), by nlohmann::json, whose parser
// keeps its own stack (a deeply nested document cannot overflow ours). Its large header is included
// by json_reader.cpp alone; callers see plain values. Pure: a function over text.
//
// The caller bounds the text before it gets here: a document is read whole, and its tree costs
// a multiple of its size.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "protocol/error.hpp"

namespace ioport {

// A JSON object's members, looked up by name; a name given twice means its last value.
class JsonObject {
  public:
    // Fails with malformed, saying where, for text that is not JSON or not an object; a number
    // beyond a double's range (1e400) is refused too. The message quotes at most ~160 bytes of
    // the parser's (which quotes what it read last, perhaps all the peer sent).
    static Result<JsonObject> parse(std::string_view text);

    bool has(std::string_view key) const;
    // The member when it is of that JSON type; nullopt when it is absent or of another type.
    std::optional<bool> boolean(std::string_view key) const;
    // A number written as a whole number from 0 to 2^64 - 1 (no sign, no fraction, no exponent).
    std::optional<std::uint64_t> unsigned_integer(std::string_view key) const;
    std::optional<std::string> string(std::string_view key) const;
    // A string, number or boolean as text: the string itself, a number as JSON writes it ("3",
    // "2.5"), "true" or "false"; nullopt for null, an array, an object, or when absent.
    std::optional<std::string> scalar_text(std::string_view key) const;
    // The member as JSON text, written anew (so valid JSON whatever the peer's spacing);
    // nullopt when absent.
    std::optional<std::string> json(std::string_view key) const;
    // The members' names, sorted.
    std::vector<std::string> keys() const;

  private:
    struct Document;
    explicit JsonObject(std::shared_ptr<const Document> document);
    std::shared_ptr<const Document> document_;
};

}  // namespace ioport
