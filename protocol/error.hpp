// Errors are values at module boundaries: every fallible call returns Result<T>.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

#include "protocol/expected.hpp"

namespace ioport {

enum class Errc {
    invalid_argument,   // a caller passed a value the protocol cannot carry
    malformed,          // bytes that are not a valid frame: wrong length, non-hex digit, noise
    error_ack,          // the module answered "0": it refused the command
    timeout,            // no complete answer within the transaction timeout
    line_noisy,         // the line never went quiet, so no request could be sent safely
    port_not_found,     // the device path does not exist
    permission_denied,  // the device exists but this user may not open it
    port_busy,          // another process holds the port exclusively
    port_lost,          // the port vanished while open (USB unplugged, pty closed)
    port_closed,        // an operation needed an open port and there is none
    io_error,           // any other operating-system error
    no_space,           // the file system is full (ENOSPC, EDQUOT)
    cancelled,          // the operation was abandoned because the owner shut down
};

struct Error {
    Errc code;
    std::string message;
};

// What a failed transaction says of the device: it did not answer, answered wrongly, refused;
// or nothing about the device, as the port is the matter, or the caller gave up.
enum class Failure { no_answer, bad_answer, error_ack, port, cancelled };
Failure failure_of(Errc code);

template <class T = void>
using Result = Expected<T, Error>;

inline Unexpected<Error> fail(Errc code, std::string message) {
    return Unexpected(Error{code, std::move(message)});
}

}  // namespace ioport

namespace ioport {

// Bytes as a person can read them in a log line: "a0\r" → "a0\\r", control bytes as \xNN.
// The one escaping of text that comes from the network (a serial line, a broker's topics, metric
// names and values, STATE payloads) before it reaches a log line or an event: every byte outside
// printable ASCII is escaped, so such text can never end a line, forge another, move the cursor or
// hide behind a Unicode direction override. At most `limit` bytes of `bytes` are shown, then "...":
// a log line stays a line however long the text a client sent.
std::string printable(std::string_view bytes, std::size_t limit = std::string_view::npos);

// The length of the valid UTF-8 sequence at the start of `text`, or 0 when there is none (an
// empty text, a stray byte, an overlong form, a surrogate, a code point past U+10FFFF).
std::size_t utf8_sequence(std::string_view text);

}  // namespace ioport
