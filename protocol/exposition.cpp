#include "protocol/exposition.hpp"

#include <cmath>

#include "protocol/json.hpp"  // append_number

namespace ioport {

void append_escaped_label(std::string& out, std::string_view value) {
    // Whole runs at a time: names and units (gateway.md §6.1) make labels long, and most of a
    // scrape is labels.
    std::size_t run = 0;
    for (std::size_t i = 0; i < value.size(); ++i) {
        const char c = value[i];
        if (c != '\\' && c != '"' && c != '\n') continue;
        out.append(value.substr(run, i - run));
        out += c == '\n' ? "\\n" : c == '"' ? "\\\"" : "\\\\";
        run = i + 1;
    }
    out.append(value.substr(run));
}

void Exposition::family(std::string_view name, std::string_view type, std::string_view help) {
    text_ += "# HELP ";
    text_ += name;
    text_ += ' ';
    // HELP escapes only \ and newline.
    for (const char c : help) {
        if (c == '\\')
            text_ += "\\\\";
        else if (c == '\n')
            text_ += "\\n";
        else
            text_ += c;
    }
    text_ += "\n# TYPE ";
    text_ += name;
    text_ += ' ';
    text_ += type;
    text_ += '\n';
}

void Exposition::labels(std::initializer_list<Label> labels) {
    if (labels.size() == 0) return;
    text_ += '{';
    bool first = true;
    for (const auto& label : labels) {
        if (!first) text_ += ',';
        first = false;
        text_ += label.name;
        text_ += "=\"";
        append_escaped_label(text_, label.value);
        text_ += '"';
    }
    text_ += '}';
}

void Exposition::sample(std::string_view name, std::initializer_list<Label> labels, double value) {
    text_ += name;
    this->labels(labels);
    if (std::isnan(value))
        text_ += " NaN\n";
    else if (std::isinf(value))
        text_ += value > 0 ? " +Inf\n" : " -Inf\n";
    else {
        text_ += ' ';
        append_number(text_, value);
        text_ += '\n';
    }
}

void Exposition::sample(std::string_view name, std::initializer_list<Label> labels,
                        std::uint64_t value) {
    text_ += name;
    this->labels(labels);
    text_ += ' ';
    append_number(text_, value);
    text_ += '\n';
}

}  // namespace ioport
