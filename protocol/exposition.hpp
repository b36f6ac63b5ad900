// The writer of Prometheus text exposition format 0.0.4 (families with HELP and TYPE, samples
// with labels), which /metrics serves and every output writes its families with
// (daemon/core/output.hpp). Pure: tested, and fuzzed through the HTTP routes, alone.
#pragma once

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <string>
#include <string_view>
#include <utility>

namespace ioport {

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
    // Room for `bytes` at once: a scrape as large as the last one then grows its text in one
    // allocation rather than doubling through every size below it.
    void reserve(std::size_t bytes) { text_.reserve(bytes); }
    std::string take() { return std::move(text_); }

  private:
    void labels(std::initializer_list<Label> labels);
    std::string text_;
};

// A label value or HELP text as 0.0.4 wants it: \ " and newline escaped.
void append_escaped_label(std::string& out, std::string_view value);

}  // namespace ioport
