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
        case Errc::no_space:
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

std::size_t utf8_sequence(std::string_view text) {
    if (text.empty()) return 0;
    const auto byte = [&](std::size_t i) { return static_cast<unsigned char>(text[i]); };
    const auto lead = byte(0);
    if (lead < 0x80) return 1;
    // The length a lead byte announces, and the range of its first continuation byte, which rules
    // out overlong forms, surrogates and code points past U+10FFFF (Unicode 15, table 3-7).
    std::size_t length = 0;
    unsigned char low = 0x80;
    unsigned char high = 0xBF;
    if (lead >= 0xC2 && lead <= 0xDF) {
        length = 2;
    } else if (lead >= 0xE0 && lead <= 0xEF) {
        length = 3;
        if (lead == 0xE0) low = 0xA0;
        if (lead == 0xED) high = 0x9F;
    } else if (lead >= 0xF0 && lead <= 0xF4) {
        length = 4;
        if (lead == 0xF0) low = 0x90;
        if (lead == 0xF4) high = 0x8F;
    } else {
        return 0;
    }
    if (text.size() < length || byte(1) < low || byte(1) > high) return 0;
    for (std::size_t i = 2; i < length; ++i)
        if (byte(i) < 0x80 || byte(i) > 0xBF) return 0;
    return length;
}

}  // namespace ioport
