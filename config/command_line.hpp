// Command lines as people type them, read by getopt_long(3): "--config=PATH", "--config PATH",
// "-c PATH", "-cPATH", clusters such as "-vV", unambiguous abbreviations ("--conf"), options
// before, between or after the operands, and "--" to end the options.
#pragma once

#include <getopt.h>

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "protocol/expected.hpp"

namespace ioport {

// One parse of one command line. getopt_long keeps its state in globals (optind, optarg, and
// more inside the C library); the constructor starts it afresh (optind = 0 makes GNU getopt
// reinitialise), so that parsing can be repeated, as the unit tests do, but two CommandLines
// must not be read in turns.
class CommandLine {
  public:
    struct Option {
        int code;                               // the short letter, or the long option's val
        std::optional<std::string_view> value;  // none given, or a required one is missing
        std::string name;                       // for messages: "-c" or "--config"
    };

    // `arguments` without the program name. `short_options` as getopt(3) takes them: "c:hV", a
    // colon after a letter that takes a value. `long_options` without the terminating zeros;
    // a long option without a letter has a val of 256 or more.
    CommandLine(std::string_view program, std::span<const std::string_view> arguments,
                std::string_view short_options, std::span<const option> long_options);
    CommandLine(const CommandLine&) = delete;
    CommandLine& operator=(const CommandLine&) = delete;

    // The next option, or nullopt after the last. An option that takes a value and has none is
    // returned without one, for the caller to say what it wants. The error says what is wrong
    // with an argument that is no option: "unknown option '-x'", "'--lo' is ambiguous: --log
    // or --log-level", "--version takes no value".
    Expected<std::optional<Option>, std::string> next();

    // The arguments that are not options, in their order; complete once next() gave nullopt.
    // They point into this object.
    const std::vector<std::string_view>& operands() const { return operands_; }

  private:
    std::string long_name(int code) const;
    std::string problem(std::string_view typed) const;

    std::vector<std::string> storage_;  // argv's strings, NUL-terminated
    std::vector<char*> argv_;
    std::string short_options_;
    std::vector<option> long_options_;
    std::vector<std::string_view> operands_;
};

}  // namespace ioport
