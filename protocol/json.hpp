// JSON written straight into a string: no document tree, as a page of a full bus (a few thousand
// values) or an MQTT message is built once and sent. Pure: the HTTP side and the MQTT JSON output
// (gateway.md §5.4, §6.3) both write with it.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <utility>

namespace ioport {

class Json {
  public:
    Json& begin_object();
    Json& end_object();
    Json& begin_array();
    Json& end_array();
    // Inside an object: the next value's name.
    Json& key(std::string_view name);
    Json& value(std::string_view text);
    Json& value(const char* text) { return value(std::string_view(text)); }
    Json& value(bool flag);
    Json& value(double number);  // NaN and infinities, which JSON lacks, as null
    Json& value(float number);   // the shortest text that reads back as this float
    Json& value(std::uint64_t number);
    Json& value(std::int64_t number);
    Json& value(int number) { return value(static_cast<std::int64_t>(number)); }
    Json& null();
    template <class T>
    Json& member(std::string_view name, const T& v) {
        key(name);
        return value(v);
    }
    std::string take() { return std::move(text_); }

  private:
    void separate();
    std::string text_;
    bool first_ = true;  // no comma before the next value or key
};

// `text` as a JSON string literal, quotes included: control characters and DEL as \u00XX, valid
// UTF-8 as it is, and each byte that does not begin a valid UTF-8 sequence (a stray continuation
// byte, a cut or overlong sequence, a surrogate, past U+10FFFF) as U+FFFD, so that the document
// is valid JSON whatever bytes a network peer put into a name or a message.
void append_json_string(std::string& out, std::string_view text);

}  // namespace ioport
