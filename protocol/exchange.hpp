// One request/reply transaction on a serial link, described as data so that the link (I/O)
// knows how to frame the reply and the protocol (pure) knows how to decode it.
#pragma once

#include <string>
#include <string_view>
#include <variant>

#include "protocol/error.hpp"
#include "protocol/id2.hpp"
#include "protocol/ioport.hpp"

namespace ioport {

using Target = std::variant<ModuleAddress, id2::Command>;

struct Exchange {
    Target target;
    std::string request;       // bytes to send, terminator included where the protocol has one
    char terminator;           // of the reply
    std::size_t reply_length;  // exact reply length before the terminator
};

// An ioport read (inputs) or command (outputs, with their 16-bit value).
Result<Exchange> make_exchange(ModuleAddress module, std::uint16_t output_value = 0);
Exchange make_exchange(id2::Command command);

// Decodes the reply frame of `exchange`. ID-2 replies come back as one word (stop input or
// counter), a reset as zero words. Errors: malformed, or error_ack for an ioport "0".
Result<Reading> decode(const Exchange& exchange, std::string_view frame);

std::string describe(const Target& target);  // "dim16 0", "ID-2 counter"

}  // namespace ioport
