// Writers of the two text formats the HTTP side serves, kept free of the daemon's types so that
// they are tested (and fuzzed through the routes) alone:
// - Prometheus text exposition format 0.0.4: families with HELP and TYPE, samples with labels;
// - JSON, written straight into a string (no document tree: a scrape of a full bus is a few
//   thousand values, built and sent once).
#pragma once

#include <cstdint>
#include <initializer_list>
#include <string>
#include <string_view>
#include <utility>

namespace ioport::daemon {

class Exposition {
  public:
    struct Label {
        std::string_view name;
        std::string_view value;
    };

    // `type`: counter, gauge or histogram. Every sample of a family follows its header.
    void family(std::string_view name, std::string_view type, std::string_view help);
    void sample(std::string_view name, std::initializer_list<Label> labels, double value);
    void sample(std::string_view name, std::initializer_list<Label> labels, std::uint64_t value);
    void sample(std::string_view name, std::initializer_list<Label> labels, int value) {
        sample(name, labels, static_cast<std::uint64_t>(value < 0 ? 0 : value));
    }
    std::string take() { return std::move(text_); }

  private:
    void labels(std::initializer_list<Label> labels);
    std::string text_;
};

// A label value or HELP text as 0.0.4 wants it: \ " and newline escaped.
void append_escaped_label(std::string& out, std::string_view value);

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

}  // namespace ioport::daemon
