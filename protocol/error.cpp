#include "protocol/error.hpp"

namespace ioport {

Failure failure_of(Errc code) {
    switch (code) {
        case Errc::timeout:
            return Failure::no_answer;
        case Errc::malformed:
        case Errc::line_noisy:
        case Errc::invalid_argument:
            return Failure::bad_answer;
        case Errc::error_ack:
            return Failure::error_ack;
        case Errc::port_not_found:
        case Errc::permission_denied:
        case Errc::port_busy:
        case Errc::port_lost:
        case Errc::port_closed:
        case Errc::io_error:
            return Failure::port;
        case Errc::cancelled:
            break;
    }
    return Failure::cancelled;
}

std::string printable(std::string_view bytes, std::size_t limit) {
    static constexpr char hex[] = "0123456789ABCDEF";
    const bool cut = bytes.size() > limit;
    if (cut) bytes = bytes.substr(0, limit);
    std::string out;
    out.reserve(bytes.size() + 8);
    for (const char c : bytes) {
        const auto u = static_cast<unsigned char>(c);
        if (c == '\r') {
            out += "\\r";
        } else if (c == '\n') {
            out += "\\n";
        } else if (c == '\\') {
            out += "\\\\";
        } else if (u < 0x20 || u >= 0x7F) {
            out += "\\x";
            out += hex[u >> 4];
            out += hex[u & 0x0F];
        } else {
            out += c;
        }
    }
    if (cut) out += "...";
    return out;
}

}  // namespace ioport
