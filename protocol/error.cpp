#include "protocol/error.hpp"

namespace ioport {

std::string_view to_string(Errc code) {
    switch (code) {
        case Errc::invalid_argument:
            return "invalid argument";
        case Errc::malformed:
            return "malformed answer";
        case Errc::error_ack:
            return "error acknowledgement";
        case Errc::timeout:
            return "no answer";
        case Errc::line_noisy:
            return "line noisy";
        case Errc::port_not_found:
            return "port not found";
        case Errc::permission_denied:
            return "permission denied";
        case Errc::port_busy:
            return "port busy";
        case Errc::port_lost:
            return "port lost";
        case Errc::port_closed:
            return "port closed";
        case Errc::io_error:
            return "I/O error";
        case Errc::cancelled:
            return "cancelled";
    }
    return "unknown error";
}

}  // namespace ioport

namespace ioport {

std::string printable(std::string_view bytes) {
    static constexpr char hex[] = "0123456789ABCDEF";
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
    return out;
}

}  // namespace ioport
