#include "protocol/json.hpp"

#include <array>
#include <charconv>
#include <cmath>
#include <ctime>
#include <iterator>

#include <fmt/format.h>

#include "protocol/error.hpp"

namespace ioport {

void append_json_string(std::string& out, std::string_view text) {
    out += '"';
    while (!text.empty()) {
        // Printable ASCII other than " and \ goes as it is, a whole run at a time: most of a
        // page is keys, ids and names of that kind.
        std::size_t plain = 0;
        while (plain < text.size()) {
            const auto c = static_cast<unsigned char>(text[plain]);
            if (c < 0x20 || c >= 0x7F || c == '"' || c == '\\') break;
            ++plain;
        }
        out.append(text.substr(0, plain));
        text.remove_prefix(plain);
        if (text.empty()) break;
        const char c = text.front();
        std::size_t used = 1;
        switch (c) {
            case '"':
                out += "\\\"";
                break;
            case '\\':
                out += "\\\\";
                break;
            case '\n':
                out += "\\n";
                break;
            case '\r':
                out += "\\r";
                break;
            case '\t':
                out += "\\t";
                break;
            default:
                if (static_cast<unsigned char>(c) < 0x20 || c == 0x7F) {
                    fmt::format_to(std::back_inserter(out), "\\u{:04x}",
                                   static_cast<unsigned char>(c));
                } else if (const auto length = utf8_sequence(text); length > 0) {
                    used = length;
                    out += text.substr(0, length);
                } else {
                    out += "\\ufffd";  // one for the stray byte; what follows is looked at anew
                }
        }
        text.remove_prefix(used);
    }
    out += '"';
}

void Json::separate() {
    if (!first_) text_ += ',';
    first_ = false;
}

Json& Json::begin_object() {
    separate();
    text_ += '{';
    first_ = true;
    return *this;
}

Json& Json::end_object() {
    text_ += '}';
    first_ = false;
    return *this;
}

Json& Json::begin_array() {
    separate();
    text_ += '[';
    first_ = true;
    return *this;
}

Json& Json::end_array() {
    text_ += ']';
    first_ = false;
    return *this;
}

Json& Json::key(std::string_view name) {
    separate();
    append_json_string(text_, name);
    text_ += ':';
    first_ = true;  // the value follows without a comma
    return *this;
}

Json& Json::value(std::string_view text) {
    separate();
    append_json_string(text_, text);
    return *this;
}

Json& Json::value(bool flag) {
    separate();
    text_ += flag ? "true" : "false";
    return *this;
}

Json& Json::value(double number) {
    if (!std::isfinite(number)) return null();
    separate();
    append_number(text_, number);
    return *this;
}

Json& Json::value(float number) {
    if (!std::isfinite(number)) return null();
    separate();
    append_number(text_, number);
    return *this;
}

Json& Json::value(std::uint64_t number) {
    separate();
    append_number(text_, number);
    return *this;
}

Json& Json::value(std::int64_t number) {
    separate();
    append_number(text_, number);
    return *this;
}

Json& Json::null() {
    separate();
    text_ += "null";
    return *this;
}

Json& Json::raw(std::string_view json) {
    separate();
    text_ += json;
    return *this;
}

std::string rfc3339(std::chrono::system_clock::time_point at) {
    const auto ms = std::chrono::floor<std::chrono::milliseconds>(at).time_since_epoch().count();
    // 32 bits on Debian 12's armhf, as is its clock's own time_t (until 2038).
    const auto seconds = static_cast<std::time_t>(ms / 1000);
    std::tm utc{};
    ::gmtime_r(&seconds, &utc);
    return fmt::format("{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z", utc.tm_year + 1900,
                       utc.tm_mon + 1, utc.tm_mday, utc.tm_hour, utc.tm_min, utc.tm_sec, ms % 1000);
}

}  // namespace ioport
