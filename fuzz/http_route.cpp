// Fuzz target: the HTTP side's routes, Host check and query parsing (daemon/http/http_route.hpp),
// and the writers of its two text formats (protocol/exposition.hpp) on arbitrary bytes.
//
// Input: a request line, "METHOD TARGET" up to the first LF or TAB (split at its first space;
// with no space, the whole line is the method and the target is empty), then, after a TAB, its
// Host fields, TAB-separated: a field "1.0" makes it HTTP/1.0, every other is a Host header's
// value. Without a TAB, the request is HTTP/1.1 with "Host: localhost", the everyday case. Then
// arbitrary bytes. The request is routed, with the names "box7" and "gateway.plant.example"; the
// target's query is asked for `format` and for the name the bytes' first line gives. The bytes
// are written as a label value, a HELP text and a JSON string, and drive the building of a JSON
// document (one operation a byte, see build_json).
//
// Invariants, from gateway.md §5.4, RFC 9110 §7.2 and RFC 9112 §3.2 (Host), the Prometheus text
// format 0.0.4 and RFC 8259 rather than from the code under test:
// - a request is refused for its Host before anything else: 400 for several Host fields, for
//   none in HTTP/1.1, or for one that is not uri-host[:port] (RFC 3986; an IP literal in
//   brackets is IPv6 without a zone); 421 for one that names neither an IPv4 or IPv6 literal,
//   localhost nor one of the names (letter case and one trailing dot aside); otherwise, and for
//   HTTP/1.0 without a Host, it routes as its method and target alone do;
// - only GET and HEAD are ever routed, and `head` says which; a route's target is a path
//   (origin form) whose part before '?' is one of the nine pages, and the page is that path's;
//   with writes served (§7.1) a POST to /api/v1/write routes to the write as well, and nothing
//   else changes; without, that path is 405 allowing nothing;
// - a refusal is 400 (not a path, or the map's format bad), 404 (a path that is no page) or 405
//   (a page, another method), with a message; only the map reads its query, and its format is
//   the first `format` parameter's value, decoded, or html when there is none;
// - query_value agrees with a decoder written here from the URL standard's form rules;
//   percent-encoding every byte of a value and asking again gives the value back;
// - an escaped label value and HELP text hold no raw newline; a label value no unescaped quote;
//   unescaping gives the bytes back; a sample is one line;
// - a JSON string literal has no raw control character nor DEL, is valid UTF-8, and parses back
//   to the bytes with each byte that begins no well-formed UTF-8 sequence (Unicode 15 §3.9: no
//   overlong form, surrogate or code point past U+10FFFF) as U+FFFD; a document
//   built with well-formed calls parses as JSON, numbers read back to the double or float
//   written, and non-finite ones are null;
// - a write's body (the bytes) is refused saying why, or is a JSON object of exactly link,
//   module, point and value, taken as they are; an Origin (the bytes' first line) is the page's
//   own only when it is the scheme and the Host, letter case aside.
#include <arpa/inet.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "daemon/http/http_route.hpp"
#include "fuzz/fuzz.hpp"
#include "protocol/exposition.hpp"
#include "protocol/json.hpp"
#include "protocol/json_reader.hpp"

namespace ioport::fuzz {
namespace {

using daemon::MapFormat;
using daemon::Page;

constexpr std::array<std::pair<std::string_view, Page>, 9> pages{{{"/", Page::status},
                                                                  {"/app.js", Page::script},
                                                                  {"/app.css", Page::style},
                                                                  {"/icon.svg", Page::icon},
                                                                  {"/api/v1/state", Page::state},
                                                                  {"/api/v1/trends", Page::trends},
                                                                  {"/metrics", Page::metrics},
                                                                  {"/healthz", Page::health},
                                                                  {"/map", Page::map}}};

std::optional<Page> page_at(std::string_view path) {
    for (const auto& [p, page] : pages)
        if (p == path) return page;
    return std::nullopt;
}

// --- Queries: application/x-www-form-urlencoded as the URL standard parses it, except that a
// malformed escape is an error rather than kept as it is (gateway.md: 400). -------------------

int hex(char c) {
    const auto* digits = "0123456789abcdef0123456789ABCDEF";
    const auto* at = std::strchr(digits, c);
    return c == '\0' || at == nullptr ? -1 : static_cast<int>((at - digits) % 16);
}

std::optional<std::string> form_decode(std::string_view text) {
    std::string out;
    std::size_t i = 0;
    while (i < text.size()) {
        if (text[i] == '%') {
            if (text.size() - i < 3 || hex(text[i + 1]) < 0 || hex(text[i + 2]) < 0)
                return std::nullopt;
            out.push_back(static_cast<char>(hex(text[i + 1]) * 16 + hex(text[i + 2])));
            i += 3;
        } else {
            out.push_back(text[i] == '+' ? ' ' : text[i]);
            ++i;
        }
    }
    return out;
}

// nullopt: absent; an empty optional inside: a malformed escape in the value. Pairs are
// separated by '&', the empty ones skipped; the name ends at the first '='.
std::optional<std::optional<std::string>> reference_value(std::string_view query,
                                                          std::string_view name) {
    std::size_t start = 0;
    for (;;) {
        const auto end = std::min(query.find('&', start), query.size());
        const auto pair = query.substr(start, end - start);
        if (!pair.empty()) {
            const auto equals = pair.find('=');
            const auto key = form_decode(pair.substr(0, equals));
            if (key && *key == name)
                return form_decode(equals == std::string_view::npos ? "" : pair.substr(equals + 1));
        }
        if (end == query.size()) return std::nullopt;
        start = end + 1;
    }
}

std::string percent_encoded(std::string_view bytes) {
    static constexpr std::string_view digits = "0123456789ABCDEF";
    std::string out;
    for (const char c : bytes) {
        const auto b = static_cast<unsigned char>(c);
        out += '%';
        out += digits[b >> 4];
        out += digits[b & 15];
    }
    return out;
}

void check_query(std::string_view query, std::string_view name) {
    if (name.empty()) return;  // the daemon asks for names only ("format")
    const auto value = daemon::query_value(query, name);
    const auto expected = reference_value(query, name);
    if (!expected) {
        check(value && !*value, "a name not in the query has no value");
        return;
    }
    if (!*expected) {
        check(!value && !value.error().empty(), "a malformed escape in the value is an error");
        return;
    }
    check(value && *value && **value == **expected, "the value is the first one, decoded");
    const auto encoded = percent_encoded(name) + "=" + percent_encoded(**expected);
    const auto again =
        daemon::query_value(percent_encoded(name) + "x=1&" + encoded + "&" + encoded + "1", name);
    check(again && *again && **again == **expected, "percent-encoding a value gives it back");
}

// --- The Host: DNS rebinding ------------------------------------------------------------------

const std::vector<std::string> server_names{"box7", "gateway.plant.example"};

enum class Verdict { served, misdirected, malformed };

bool digits(std::string_view text) {
    return std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; });
}

bool is_address(int family, std::string_view text) {
    std::array<unsigned char, 16> address{};
    return text.find('\0') == std::string_view::npos &&
           ::inet_pton(family, std::string(text).c_str(), address.data()) == 1;
}

std::string folded(std::string_view name) {
    if (!name.empty() && name.back() == '.') name.remove_suffix(1);
    std::string out;
    for (const char c : name)
        out += c >= 'A' && c <= 'Z' ? static_cast<char>(c + 32) : c;
    return out;
}

// RFC 9110 §7.2: Host = uri-host [ ":" port ], port = *DIGIT; IP-literal = "[" IPv6address "]".
Verdict verdict(std::string_view host) {
    std::string_view name = host;
    std::string_view port;
    if (host.starts_with('[')) {
        const auto close = host.find(']');
        if (close == std::string_view::npos) return Verdict::malformed;
        name = host.substr(1, close - 1);
        port = host.substr(close + 1);
        if (!port.empty() && (port[0] != ':' || !digits(port.substr(1)))) return Verdict::malformed;
        return is_address(AF_INET6, name) ? Verdict::served : Verdict::malformed;
    }
    const auto colon = host.find(':');
    if (colon != std::string_view::npos) {
        name = host.substr(0, colon);
        if (!digits(host.substr(colon + 1))) return Verdict::malformed;
    }
    if (is_address(AF_INET, name)) return Verdict::served;
    const auto folded_name = folded(name);
    if (folded_name == "localhost") return Verdict::served;
    for (const auto& n : server_names)
        if (folded(n) == folded_name) return Verdict::served;
    return Verdict::misdirected;
}

// True when the Host lets the request through to its method and target.
bool check_host(const daemon::Request& request) {
    const auto routed = daemon::route(request, server_names);
    const auto alone = daemon::route(request.method, request.target);
    const auto refused = [&](unsigned status) {
        check(!routed && routed.error().status == status && !routed.error().message.empty(),
              "a Host refusal is its status, with a message");
        return false;
    };
    if (request.hosts > 1) return refused(400);
    if (request.hosts == 0 && request.version == 11) return refused(400);
    if (request.hosts == 1) {
        switch (verdict(request.host)) {
            case Verdict::malformed:
                return refused(400);
            case Verdict::misdirected:
                return refused(421);
            case Verdict::served:
                break;
        }
    }
    check(routed.has_value() == alone.has_value() &&
              (routed ? *routed == *alone : routed.error() == alone.error()),
          "a request whose Host is served routes as its method and target do");
    return true;
}

// --- Routes ------------------------------------------------------------------------------

// POST /api/v1/write (gateway.md §7.1): with writes served, a POST there routes to the write and
// nothing else does; without, the path is a 405 whatever the method. Every other target routes
// the same either way.
void check_write_route(std::string_view method, std::string_view target) {
    const auto with = daemon::route(method, target, true);
    const auto without = daemon::route(method, target, false);
    const auto path = target.substr(0, target.find('?'));
    if (path != "/api/v1/write") {
        check(with.has_value() == without.has_value() &&
                  (with ? *with == *without : with.error() == without.error()),
              "writes served change no route but the write's");
        check(!with || with->page != Page::write, "only /api/v1/write is the write");
        return;
    }
    check(!without && without.error().status == 405 && without.error().allow.empty(),
          "without writes the write path is 405, allowing nothing");
    check(with.has_value() == (method == "POST"), "with writes only a POST there routes");
    if (with)
        check(with->page == Page::write && !with->head, "and it routes to the write");
    else
        check(with.error().status == 405 && with.error().allow == "POST",
              "another method there is 405, allowing POST");
}

// A write's body is taken whole or refused saying why; one taken has its four members, as the
// JSON object gave them.
void check_write_body(std::string_view bytes) {
    const auto write = daemon::parse_write_body(bytes);
    if (!write) {
        check(!write.error().empty(), "a refused body says why");
        return;
    }
    const auto object = JsonObject::parse(bytes);
    check(object.has_value(), "a body taken is a JSON object");
    const auto keys = object->keys();
    check(keys == std::vector<std::string>{"link", "module", "point", "value"},
          "a body taken has the four members and no other");
    check(object->string("link") == write->link && object->string("module") == write->module &&
              object->string("point") == write->point &&
              object->scalar_text("value") == write->value,
          "a body taken is the members' values");
}

// The Origin of a browser's POST is the page's own exactly when it is the scheme and the Host.
void check_origin(std::string_view host, std::string_view bytes) {
    check(daemon::same_origin("", false, host), "no Origin is no page of another site");
    for (const bool tls : {false, true}) {
        const auto own = std::string(tls ? "https://" : "http://") + std::string(host);
        check(daemon::same_origin(own, tls, host), "the page's own origin is the same");
        check(!daemon::same_origin(own, !tls, host), "the other scheme is another origin");
        const auto lower = [](std::string_view text) {
            std::string out(text);
            for (auto& c : out)
                c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
            return out;
        };
        if (!bytes.empty())
            check(!daemon::same_origin(bytes, tls, host) || lower(bytes) == lower(own),
                  "an Origin taken is the page's own, letter case aside");
    }
}

void check_route(std::string_view method, std::string_view target) {
    const auto routed = daemon::route(method, target);
    const bool get_or_head = method == "GET" || method == "HEAD";
    const bool origin_form = target.starts_with('/');
    const auto question = target.find('?');
    const auto path = target.substr(0, question);
    const auto query =
        question == std::string_view::npos ? std::string_view() : target.substr(question + 1);
    const auto page = origin_form ? page_at(path) : std::nullopt;
    const auto again = daemon::route(method, target);
    check(again.has_value() == routed.has_value() &&
              (routed ? *again == *routed : again.error() == routed.error()),
          "the same request line routes the same way");
    if (routed) {
        check(get_or_head, "only GET and HEAD are routed");
        check(routed->head == (method == "HEAD"), "head says whether it was HEAD");
        check(origin_form && page && *page == routed->page,
              "a route's path is one of the nine pages, and the page is that path's");
        if (routed->page != Page::map) {
            check(routed->format == MapFormat::html, "only the map has a format");
            return;
        }
        const auto format = reference_value(query, "format");
        check(!format || (*format && (**format == "html" || **format == "csv" || **format == "md")),
              "a routed map's format is absent, html, csv or md");
        const auto expected = !format             ? MapFormat::html
                              : **format == "csv" ? MapFormat::csv
                              : **format == "md"  ? MapFormat::markdown
                                                  : MapFormat::html;
        check(routed->format == expected, "the map's format is the first format parameter's");
        return;
    }
    const auto& refusal = routed.error();
    check(!refusal.message.empty(), "a refusal says why");
    if (!origin_form) {
        check(refusal.status == 400, "a target that is not a path is 400");
    } else if (path == "/api/v1/write") {
        check(refusal.status == 405, "the write path without writes served is 405");
    } else if (!page) {
        check(refusal.status == 404, "a path that is no page is 404");
    } else if (!get_or_head) {
        check(refusal.status == 405, "another method on a page is 405");
    } else {
        const auto format = reference_value(query, "format");
        check(refusal.status == 400 && *page == Page::map && format &&
                  (!*format || (**format != "html" && **format != "csv" && **format != "md")),
              "GET or HEAD of a page is refused only for the map's bad format");
    }
}

// --- Prometheus text ------------------------------------------------------------------------

// The bytes an escaped text stands for, or nullopt when it has an escape that 0.0.4 lacks.
// `quote`: label values escape '"' as well.
std::optional<std::string> unescaped(std::string_view text, bool quote) {
    std::string out;
    for (std::size_t i = 0; i < text.size(); ++i) {
        if (text[i] != '\\') {
            out += text[i];
            continue;
        }
        if (++i == text.size()) return std::nullopt;
        if (text[i] == '\\')
            out += '\\';
        else if (text[i] == 'n')
            out += '\n';
        else if (quote && text[i] == '"')
            out += '"';
        else
            return std::nullopt;
    }
    return out;
}

bool has_unescaped_quote(std::string_view text) {
    for (std::size_t i = 0; i < text.size(); ++i) {
        if (text[i] == '\\')
            ++i;
        else if (text[i] == '"')
            return true;
    }
    return false;
}

void check_exposition(std::string_view bytes) {
    std::string label;
    append_escaped_label(label, bytes);
    check(label.find('\n') == std::string::npos, "an escaped label holds no raw newline");
    check(!has_unescaped_quote(label), "an escaped label holds no unescaped quote");
    check(unescaped(label, true) == std::string(bytes), "an escaped label unescapes to its bytes");

    Exposition e;
    e.family("ioportd_fuzz", "gauge", bytes);
    e.sample("ioportd_fuzz", {{"link", bytes}, {"module", "dim16 0"}}, std::uint64_t{7});
    const auto text = e.take();
    const std::string help_prefix = "# HELP ioportd_fuzz ";
    const auto help_end = text.find('\n');
    check(text.starts_with(help_prefix) && help_end != std::string::npos,
          "a family starts with its HELP line");
    const auto help =
        std::string_view(text).substr(help_prefix.size(), help_end - help_prefix.size());
    check(unescaped(help, false) == std::string(bytes), "HELP unescapes to its text");
    const auto rest = std::string_view(text).substr(help_end + 1);
    const std::string sample = "ioportd_fuzz{link=\"" + label + "\",module=\"dim16 0\"} 7\n";
    check(rest == "# TYPE ioportd_fuzz gauge\n" + sample,
          "TYPE, then the sample on one line with its labels in order");
}

// --- JSON -------------------------------------------------------------------------------------

// A strict RFC 8259 reader; the strings' bytes decoded (\u00XX as byte XX; others kept as
// escapes, which the writer never produces).
// A code point below U+10000 as UTF-8 (what a \uXXXX escape stands for).
void append_utf8(std::string& out, std::uint32_t code) {
    if (code < 0x80) {
        out += static_cast<char>(code);
    } else if (code < 0x800) {
        out += static_cast<char>(0xC0 | code >> 6);
        out += static_cast<char>(0x80 | (code & 0x3F));
    } else {
        out += static_cast<char>(0xE0 | code >> 12);
        out += static_cast<char>(0x80 | (code >> 6 & 0x3F));
        out += static_cast<char>(0x80 | (code & 0x3F));
    }
}

class JsonReader {
  public:
    explicit JsonReader(std::string_view text) : text_(text) {}
    bool document() { return value(0) && at_ == text_.size(); }
    std::optional<std::string> string() {
        if (!eat('"')) return std::nullopt;
        std::string out;
        while (at_ < text_.size()) {
            const char c = text_[at_++];
            if (c == '"') return out;
            if (static_cast<unsigned char>(c) < 0x20) return std::nullopt;
            if (c != '\\') {
                out += c;
                continue;
            }
            if (at_ == text_.size()) return std::nullopt;
            const char e = text_[at_++];
            switch (e) {
                case '"':
                case '\\':
                case '/':
                    out += e;
                    break;
                case 'b':
                    out += '\b';
                    break;
                case 'f':
                    out += '\f';
                    break;
                case 'n':
                    out += '\n';
                    break;
                case 'r':
                    out += '\r';
                    break;
                case 't':
                    out += '\t';
                    break;
                case 'u': {
                    if (text_.size() - at_ < 4) return std::nullopt;
                    int code = 0;
                    for (int k = 0; k < 4; ++k) {
                        const int d = hex(text_[at_++]);
                        if (d < 0) return std::nullopt;
                        code = code * 16 + d;
                    }
                    append_utf8(out, static_cast<std::uint32_t>(code));
                    break;
                }
                default:
                    return std::nullopt;
            }
        }
        return std::nullopt;
    }
    // The numbers read, in order, as their text.
    std::vector<std::string> numbers;

  private:
    bool eat(char c) {
        if (at_ < text_.size() && text_[at_] == c) {
            ++at_;
            return true;
        }
        return false;
    }
    bool literal(std::string_view word) {
        if (text_.substr(at_, word.size()) != word) return false;
        at_ += word.size();
        return true;
    }
    bool number() {
        const auto start = at_;
        eat('-');
        if (eat('0')) {
        } else if (digits() == 0) {
            return false;
        }
        if (eat('.') && digits() == 0) return false;
        if (eat('e') || eat('E')) {
            if (!eat('+')) eat('-');
            if (digits() == 0) return false;
        }
        numbers.emplace_back(text_.substr(start, at_ - start));
        return true;
    }
    std::size_t digits() {
        const auto start = at_;
        while (at_ < text_.size() && text_[at_] >= '0' && text_[at_] <= '9')
            ++at_;
        return at_ - start;
    }
    bool value(int depth) {
        if (depth > 200 || at_ >= text_.size()) return false;
        const char c = text_[at_];
        if (c == '{') {
            ++at_;
            if (eat('}')) return true;
            do {
                if (!string() || !eat(':') || !value(depth + 1)) return false;
            } while (eat(','));
            return eat('}');
        }
        if (c == '[') {
            ++at_;
            if (eat(']')) return true;
            do {
                if (!value(depth + 1)) return false;
            } while (eat(','));
            return eat(']');
        }
        if (c == '"') return string().has_value();
        if (c == 't') return literal("true");
        if (c == 'f') return literal("false");
        if (c == 'n') return literal("null");
        return number();
    }

    std::string_view text_;
    std::size_t at_ = 0;
};

// The bytes as a JSON reader must see them: each well-formed UTF-8 sequence as it is, any other
// byte as U+FFFD. Decoded the long way (bits, then the range the length allows), not by the
// table of first-continuation ranges the writer uses.
std::string well_formed(std::string_view bytes) {
    std::string out;
    std::size_t at = 0;
    while (at < bytes.size()) {
        const auto lead = static_cast<unsigned char>(bytes[at]);
        const std::size_t length = lead < 0x80         ? 1
                                   : lead >> 5 == 0x6  ? 2
                                   : lead >> 4 == 0xE  ? 3
                                   : lead >> 3 == 0x1E ? 4
                                                       : 0;
        std::uint32_t code = length == 1   ? lead
                             : length == 2 ? lead & 0x1Fu
                             : length == 3 ? lead & 0x0Fu
                                           : lead & 0x07u;
        bool ok = length > 0 && at + length <= bytes.size();
        for (std::size_t k = 1; ok && k < length; ++k) {
            const auto next = static_cast<unsigned char>(bytes[at + k]);
            ok = next >> 6 == 0x2;
            code = code << 6 | (next & 0x3Fu);
        }
        constexpr std::array<std::uint32_t, 5> least{0, 0, 0x80, 0x800, 0x10000};
        ok = ok && code >= least[length] && code <= 0x10FFFF && (code < 0xD800 || code > 0xDFFF);
        if (ok) {
            out += bytes.substr(at, length);
            at += length;
        } else {
            out += "\xEF\xBF\xBD";  // U+FFFD
            ++at;
        }
    }
    return out;
}

void check_json_string(std::string_view bytes) {
    std::string literal;
    append_json_string(literal, bytes);
    for (const char c : literal)
        check(static_cast<unsigned char>(c) >= 0x20 && c != 0x7F,
              "a JSON string holds no raw control byte nor DEL");
    check(well_formed(literal) == literal, "a JSON string literal is valid UTF-8");
    JsonReader reader(literal);
    const auto back = reader.string();
    check(back && *back == well_formed(bytes),
          "a JSON string literal reads back to its bytes, U+FFFD for what is not UTF-8");
}

// A number written, which it must read back as.
struct Written {
    enum Kind { f64, f32, i64, u64, null } kind = null;
    double f64_value = 0;
    float f32_value = 0;
    std::int64_t i64_value = 0;
    std::uint64_t u64_value = 0;
};

// Builds a document from the bytes, one operation a byte (the low 3 bits), keeping the calls
// well formed as the daemon's renderers do: keys only in objects, and before every value there;
// the containers still open are closed at the end.
std::string build_json(std::string_view bytes, std::vector<Written>& numbers) {
    Json json;
    std::vector<char> open{'{'};  // a document is an object, as every page's is
    json.begin_object();
    std::size_t i = 0;
    const auto take = [&](std::size_t n) {
        const auto piece = bytes.substr(std::min(i, bytes.size()), n);
        i += n;
        return piece;
    };
    // In an object, every value comes after its key.
    const auto before_value = [&] {
        if (open.back() == '{') json.key(take(2));
    };
    while (i < bytes.size() && open.size() < 64) {
        const auto op = static_cast<unsigned char>(bytes[i++]);
        switch (op & 7) {
            case 0:
                before_value();
                json.begin_object();
                open.push_back('{');
                break;
            case 1:
                before_value();
                json.begin_array();
                open.push_back('[');
                break;
            case 2:
                if (open.size() > 1) {
                    if (open.back() == '{')
                        json.end_object();
                    else
                        json.end_array();
                    open.pop_back();
                }
                break;
            case 3:
                before_value();
                json.value(take(op >> 3));
                break;
            case 4: {
                before_value();
                double d = 0;
                const auto piece = take(sizeof d);
                std::memcpy(&d, piece.data(), piece.size());
                json.value(d);
                Written w{};
                if (std::isfinite(d)) {
                    w.kind = Written::f64;
                    w.f64_value = d;
                }
                numbers.push_back(w);
                break;
            }
            case 5: {
                before_value();
                float f = 0;
                const auto piece = take(sizeof f);
                std::memcpy(&f, piece.data(), piece.size());
                json.value(f);
                Written w{};
                if (std::isfinite(f)) {
                    w.kind = Written::f32;
                    w.f32_value = f;
                }
                numbers.push_back(w);
                break;
            }
            case 6: {
                before_value();
                std::int64_t n = 0;
                const auto piece = take(sizeof n);
                std::memcpy(&n, piece.data(), piece.size());
                Written w{};
                if (op & 8) {
                    json.value(n);
                    w.kind = Written::i64;
                    w.i64_value = n;
                } else {
                    w.kind = Written::u64;
                    w.u64_value = static_cast<std::uint64_t>(n);
                    json.value(w.u64_value);
                }
                numbers.push_back(w);
                break;
            }
            default:
                before_value();
                if (op & 8)
                    json.null();
                else
                    json.value((op & 16) != 0);
                break;
        }
    }
    while (!open.empty()) {
        if (open.back() == '{')
            json.end_object();
        else
            json.end_array();
        open.pop_back();
    }
    return json.take();
}

void check_json(std::string_view bytes) {
    check_json_string(bytes);
    std::vector<Written> written;
    const auto text = build_json(bytes, written);
    JsonReader reader(text);
    check(reader.document(), "a document built with well-formed calls is JSON");
    // Every number the reader met, in order, is one written (the keys and strings hold none).
    std::size_t n = 0;
    for (const auto& w : written) {
        if (w.kind == Written::null) continue;
        check(n < reader.numbers.size(), "every finite number is written as a number");
        const auto& t = reader.numbers[n++];
        switch (w.kind) {
            case Written::f64:
                check(std::strtod(t.c_str(), nullptr) == w.f64_value,
                      "a double reads back as itself");
                break;
            case Written::f32:
                check(std::strtof(t.c_str(), nullptr) == w.f32_value,
                      "a float reads back as itself");
                check(t.size() <= 16, "a float is written in its shortest form");
                break;
            case Written::i64:
                check(std::strtoll(t.c_str(), nullptr, 10) == w.i64_value && t.find('.') == t.npos,
                      "an integer is written as itself");
                break;
            case Written::u64:
                check(std::strtoull(t.c_str(), nullptr, 10) == w.u64_value &&
                          t.find_first_not_of("0123456789") == t.npos,
                      "an unsigned integer is written as itself");
                break;
            case Written::null:
                break;
        }
    }
    check(n == reader.numbers.size(), "no number but those written");
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace ioport;
    const std::string_view input(reinterpret_cast<const char*>(data), size);
    const auto newline = input.find('\n');
    const auto whole_line = input.substr(0, newline);
    const auto bytes =
        newline == std::string_view::npos ? std::string_view() : input.substr(newline + 1);
    const auto tab = whole_line.find('\t');
    const auto line = whole_line.substr(0, tab);
    const auto space = line.find(' ');
    const auto method = line.substr(0, space);
    const auto target =
        space == std::string_view::npos ? std::string_view() : line.substr(space + 1);

    daemon::Request request{method, target, 11, 1, "localhost"};
    if (tab != std::string_view::npos) {
        request.hosts = 0;
        auto fields = whole_line.substr(tab + 1);
        for (;;) {
            const auto end = fields.find('\t');
            const auto field = fields.substr(0, end);
            if (field == "1.0") {
                request.version = 10;
            } else if (request.hosts++ == 0) {
                request.host = field;
            }
            if (end == std::string_view::npos) break;
            fields = fields.substr(end + 1);
        }
    }
    fuzz::check_host(request);
    fuzz::check_route(method, target);
    fuzz::check_write_route(method, target);
    const auto question = target.find('?');
    const auto query =
        question == std::string_view::npos ? std::string_view() : target.substr(question + 1);
    fuzz::check_query(query, "format");
    fuzz::check_query(query, bytes.substr(0, bytes.find('\n')));
    fuzz::check_exposition(bytes);
    fuzz::check_json(bytes);
    fuzz::check_write_body(bytes);
    fuzz::check_origin(request.host, bytes.substr(0, bytes.find('\n')));
    return 0;
}
