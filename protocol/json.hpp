// JSON written straight into a string: no document tree, as a page of a full bus (a few thousand
// values) or an MQTT message is built once and sent. Pure: the HTTP side and the MQTT JSON output
// (gateway.md §5.4, §6.3) both write with it.
#pragma once

#include <array>
#include <charconv>
#include <chrono>
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
    // A value that is JSON text already (a member a peer sent, as JsonObject::json gives it).
    Json& raw(std::string_view json);
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

// A number in the shortest text that reads back as the same value (std::to_chars: exact by the
// standard, whatever the compiler). fmt 9.1's "{}" is exact too when g++ compiles it, but its
// header code as clang 14 compiles it writes subnormal doubles to one digit
// (7.6485216289552275e-309 as "8e-309"), which the fuzz target found. JSON and the Prometheus
// exposition both write numbers so.
template <class T>
void append_number(std::string& out, T value) {
    std::array<char, 32> text;  // the longest double, "-2.2250738585072014e-308", is 24
    const auto written = std::to_chars(text.data(), text.data() + text.size(), value);
    out.append(text.data(), written.ptr);
}

// A time as the JSON documents give it: RFC 3339 in UTC, to the millisecond
// ("2026-12-02T03:50:00.123Z").
std::string rfc3339(std::chrono::system_clock::time_point at);

}  // namespace ioport
