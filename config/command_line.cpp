#include "config/command_line.hpp"

#include <algorithm>

#include <fmt/format.h>

namespace ioport {

CommandLine::CommandLine(std::string_view program, std::span<const std::string_view> arguments,
                         std::string_view short_options, std::span<const option> long_options)
    : storage_{std::string(program)},
      // "-": operands are returned in order, as code 1, whatever POSIXLY_CORRECT says (which would
      // otherwise end the options at the first operand). ":": a missing value is reported as ':'
      // rather than '?', and getopt prints nothing.
      short_options_(fmt::format("-:{}", short_options)),
      long_options_(long_options.begin(), long_options.end()) {
    storage_.insert(storage_.end(), arguments.begin(), arguments.end());
    for (auto& argument : storage_)
        argv_.push_back(argument.data());
    argv_.push_back(nullptr);
    long_options_.push_back({});
    optind = 0;  // GNU: start over, forgetting the previous command line
    opterr = 0;  // the caller words the messages
}

Expected<std::optional<CommandLine::Option>, std::string> CommandLine::next() {
    const int argc = static_cast<int>(argv_.size()) - 1;
    for (;;) {
        // The argument getopt is at, also in the middle of "-vV" (optind moves on after the V).
        const int current = std::max(optind, 1);
        const std::string_view at = current < argc ? argv_[static_cast<std::size_t>(current)] : "";
        const bool long_form = at.starts_with("--");
        int index = -1;
        const int code =
            getopt_long(argc, argv_.data(), short_options_.c_str(), long_options_.data(), &index);
        switch (code) {
            case -1:
                for (int i = optind; i < argc; ++i)  // after "--"
                    operands_.emplace_back(argv_[static_cast<std::size_t>(i)]);
                return std::nullopt;
            case 1:
                operands_.emplace_back(optarg);
                continue;
            case ':':
                return Option{
                    optopt, std::nullopt,
                    long_form ? long_name(optopt) : fmt::format("-{}", static_cast<char>(optopt))};
            case '?':
                return Unexpected(
                    problem(long_form ? at : fmt::format("-{}", static_cast<char>(optopt))));
            default:
                break;  // an option
        }
        std::string name = index >= 0 ? fmt::format("--{}", long_options_[index].name)
                                      : fmt::format("-{}", static_cast<char>(code));
        std::optional<std::string_view> value;
        if (optarg != nullptr) value = optarg;
        return Option{code, value, std::move(name)};
    }
}

std::string CommandLine::long_name(int code) const {
    const auto found = std::ranges::find(long_options_, code, &option::val);
    if (found == long_options_.end() || found->name == nullptr)
        return fmt::format("-{}", static_cast<char>(code));
    return fmt::format("--{}", found->name);
}

std::string CommandLine::problem(std::string_view typed) const {
    const auto name = typed.substr(0, typed.find('='));
    if (!name.starts_with("--")) return fmt::format("unknown option '{}'", name);
    // getopt_long says '?' for three things: a value given to an option that takes none, an
    // abbreviation of more than one option, and a name it does not know.
    const auto given = name.substr(2);
    std::vector<std::string> matches;
    for (const auto& candidate : long_options_) {
        if (candidate.name == nullptr) continue;
        const std::string_view full = candidate.name;
        if (full == given) return fmt::format("{} takes no value", name);
        if (full.starts_with(given)) matches.push_back(fmt::format("--{}", full));
    }
    if (matches.size() > 1)
        return fmt::format("'{}' is ambiguous: {}", name, fmt::join(matches, " or "));
    if (matches.size() == 1) return fmt::format("{} takes no value", matches.front());
    return fmt::format("unknown option '{}'", name);
}

}  // namespace ioport
