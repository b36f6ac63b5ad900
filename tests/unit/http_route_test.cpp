// The HTTP side's pure parts (gateway.md §5.4): routes and queries, the Prometheus and JSON
// writers, the request-duration histogram, the trend ring and the /proc parsers of the process
// metrics (the boot time is no longer parsed: since 8bb9b30 it is the realtime clock less the
// boot clock, /proc/stat being hidden by the unit's ProcSubset=pid).
#include <array>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "daemon/core/histogram.hpp"
#include "daemon/core/trend.hpp"
#include "daemon/http/http_route.hpp"
#include "daemon/http/process_stats.hpp"
#include "protocol/exposition.hpp"
#include "protocol/json.hpp"

namespace ioport::daemon {
namespace {

using namespace std::string_literals;

// --- route() ---------------------------------------------------------------------------------

constexpr std::string_view index_hint =
    "pages here: / (status), /api/v1/state, /api/v1/trends, /metrics, /healthz, /map; "
    "POST /api/v1/write";

unsigned status(std::string_view method, std::string_view target) {
    const auto routed = route(method, target);
    return routed ? 200 : routed.error().status;
}

TEST(HttpRoute, GetAndHeadReachEveryPage) {
    const std::vector<std::pair<std::string_view, Page>> pages{{"/", Page::status},
                                                               {"/app.js", Page::script},
                                                               {"/app.css", Page::style},
                                                               {"/icon.svg", Page::icon},
                                                               {"/api/v1/state", Page::state},
                                                               {"/api/v1/trends", Page::trends},
                                                               {"/metrics", Page::metrics},
                                                               {"/healthz", Page::health},
                                                               {"/map", Page::map}};
    for (const auto& [path, page] : pages) {
        SCOPED_TRACE(path);
        EXPECT_EQ(route("GET", path), (Route{page, MapFormat::html, false}));
        EXPECT_EQ(route("HEAD", path), (Route{page, MapFormat::html, true}));
    }
}

TEST(HttpRoute, OtherMethodsAre405OnEveryPage) {
    for (const auto path : {"/", "/app.js", "/app.css", "/icon.svg", "/api/v1/state",
                            "/api/v1/trends", "/metrics", "/healthz", "/map"})
        for (const auto method : {"POST", "PUT", "DELETE", "PATCH", "OPTIONS", "get", "head"}) {
            SCOPED_TRACE(fmt::format("{} {}", method, path));
            const auto routed = route(method, path);
            ASSERT_FALSE(routed);
            EXPECT_EQ(routed.error(),
                      (Refusal{405, "this page is read-only: use GET (or HEAD)", "GET, HEAD"}));
            EXPECT_EQ(route(method, path, true).error(),
                      routed.error());  // writes: still only there
        }
}

// gateway.md §7.1: POST /api/v1/write is the one write, and only where a web configuration is
// given; without one the path is there to say why it takes nothing (405 with an empty Allow,
// RFC 9110 §10.2.1: no method).
TEST(HttpRoute, TheWritePathTakesAPostOnlyWhereWritesAreServed) {
    EXPECT_EQ(route("POST", "/api/v1/write", true), (Route{Page::write, MapFormat::html, false}));
    EXPECT_EQ(route("POST", "/api/v1/write?x=1", true),
              (Route{Page::write, MapFormat::html, false}));
    for (const auto method : {"GET", "HEAD", "PUT", "post"}) {
        SCOPED_TRACE(method);
        EXPECT_EQ(route(method, "/api/v1/write", true).error(),
                  (Refusal{405, "a write is a POST with a JSON body", "POST"}));
    }
    for (const auto method : {"POST", "GET"}) {
        SCOPED_TRACE(method);
        const auto refused = route(method, "/api/v1/write", false).error();
        EXPECT_EQ(refused.status, 405U);
        EXPECT_EQ(refused.allow, "");
        EXPECT_NE(refused.message.find("http.web_config_file"), std::string::npos);
    }
    EXPECT_EQ(status("POST", "/api/v1/write/"), 404U);
}

// What a browser sends as Origin is the address bar's scheme, host and port; a page of any other
// origin, or one opened from a file (Origin: null), is not the status page.
TEST(HttpOrigin, OnlyThePagesOwnOriginOrNoneAtAll) {
    EXPECT_TRUE(same_origin("", false, "127.0.0.1:8080"));  // curl, a script: no Origin
    EXPECT_TRUE(same_origin("http://127.0.0.1:8080", false, "127.0.0.1:8080"));
    EXPECT_TRUE(same_origin("https://box7:8443", true, "box7:8443"));
    EXPECT_TRUE(same_origin("HTTP://Box7:8080", false, "box7:8080"));
    EXPECT_TRUE(same_origin("http://[::1]:8080", false, "[::1]:8080"));
    EXPECT_FALSE(same_origin("http://127.0.0.1:8080", true, "127.0.0.1:8080"));  // scheme
    EXPECT_FALSE(same_origin("https://127.0.0.1:8080", false, "127.0.0.1:8080"));
    EXPECT_FALSE(same_origin("http://127.0.0.1:8081", false, "127.0.0.1:8080"));  // port
    EXPECT_FALSE(same_origin("http://127.0.0.1", false, "127.0.0.1:8080"));
    EXPECT_FALSE(same_origin("http://evil.example", false, "127.0.0.1:8080"));
    EXPECT_FALSE(same_origin("null", false, "127.0.0.1:8080"));
    EXPECT_FALSE(same_origin("http://127.0.0.1:8080/", false, "127.0.0.1:8080"));
}

TEST(HttpWriteBody, TheFourMembersWithTheValueAsAPlainMqttSetTakesIt) {
    EXPECT_EQ(parse_write_body(R"({"link": "hub0", "module": "dom16_0", "point": "out3", )"
                               R"("value": "ON"})"),
              (WriteBody{"hub0", "dom16_0", "out3", "ON"}));
    EXPECT_EQ(parse_write_body(R"({"value": true, "point": "out3", "module": "m", "link": "l"})"),
              (WriteBody{"l", "m", "out3", "true"}));
    EXPECT_EQ(parse_write_body(R"({"link": "l", "module": "m", "point": "pos", "value": 7})"),
              (WriteBody{"l", "m", "pos", "7"}));
}

TEST(HttpWriteBody, AnythingElseSaysWhatIsWrong) {
    const auto error = [](std::string_view body) {
        const auto parsed = parse_write_body(body);
        EXPECT_FALSE(parsed) << body;
        return parsed ? std::string() : parsed.error();
    };
    constexpr std::string_view example =
        R"(: {"link": "hub0", "module": "dom16_0", "point": "out3", "value": "ON"})";
    EXPECT_TRUE(error("").starts_with("the body is "));
    EXPECT_TRUE(error("[1]").starts_with("the body is "));
    EXPECT_TRUE(error(R"({"link": "l")").starts_with("the body is "));
    // Beyond a double's range: refused, not thrown (it ended the daemon).
    EXPECT_TRUE(error(R"({"link": "l", "module": "m", "point": "p", "value": 1e400})")
                    .starts_with("the body is not JSON: number overflow parsing '1e400'"));
    EXPECT_EQ(error(R"({"module": "m", "point": "p", "value": 1})"),
              fmt::format("link: a string is missing{}", example));
    EXPECT_EQ(error(R"({"link": 1, "module": "m", "point": "p", "value": 1})"),
              fmt::format("link: a string is missing{}", example));
    EXPECT_EQ(error(R"({"link": "l", "module": "m", "point": "p"})"),
              fmt::format("value: a string, number or boolean is missing, as a plain MQTT set "
                          "takes it{}",
                          example));
    EXPECT_EQ(error(R"({"link": "l", "module": "m", "point": "p", "value": [1]})").substr(0, 6),
              "value:");
    EXPECT_EQ(error(R"({"link": "l", "module": "m", "point": "p", "value": null})").substr(0, 6),
              "value:");
    EXPECT_EQ(error(R"({"link": "l", "module": "m", "point": "p", "value": 1, "user": "x"})"),
              fmt::format("'user' is not a member of a write{}", example));
}

TEST(HttpRoute, UnknownPathsAre404WhateverTheMethod) {
    for (const auto path : {"/metrics/", "/Metrics", "/api/v1", "/api/v1/state/", "//metrics",
                            "/metrics#x", "/%6detrics", "/index.html", "/map/", "/app.js/",
                            "/App.js", "/status_page/app.js", "/favicon.ico"}) {
        SCOPED_TRACE(path);
        const auto routed = route("GET", path);
        ASSERT_FALSE(routed);
        EXPECT_EQ(routed.error(), (Refusal{404, "no page at this path; "s + index_hint.data()}));
        EXPECT_EQ(status("POST", path), 404U);  // the path first: nothing to be read-only about
    }
}

// An empty target is not a path either: RFC 9112's origin form is "/" and more. It is refused as
// malformed (400), as the absolute form and "*" are, not as a page that is not there.
TEST(HttpRoute, TargetsThatAreNotPathsAre400) {
    for (const auto target : {"http://x/metrics", "*", "", "metrics", "?format=csv"}) {
        SCOPED_TRACE(target);
        const auto routed = route("GET", target);
        ASSERT_FALSE(routed);
        EXPECT_EQ(routed.error(),
                  (Refusal{400, "the request target must be a path such as /metrics; "s +
                                    index_hint.data()}));
        EXPECT_EQ(status("POST", target), 400U);
    }
}

TEST(HttpRoute, QueriesAreIgnoredExceptTheMapsFormat) {
    EXPECT_EQ(route("GET", "/metrics?format=bad"), (Route{Page::metrics, MapFormat::html, false}));
    EXPECT_EQ(route("GET", "/api/v1/state?%zz"), (Route{Page::state, MapFormat::html, false}));
    EXPECT_EQ(route("GET", "/?"), (Route{Page::status, MapFormat::html, false}));
}

TEST(HttpRoute, MapFormats) {
    EXPECT_EQ(route("GET", "/map?format=csv"), (Route{Page::map, MapFormat::csv, false}));
    EXPECT_EQ(route("GET", "/map?format=md"), (Route{Page::map, MapFormat::markdown, false}));
    EXPECT_EQ(route("GET", "/map?format=html"), (Route{Page::map, MapFormat::html, false}));
    EXPECT_EQ(route("HEAD", "/map?format=csv"), (Route{Page::map, MapFormat::csv, true}));
    EXPECT_EQ(route("GET", "/map?"), (Route{Page::map, MapFormat::html, false}));
    EXPECT_EQ(route("GET", "/map?other=1"), (Route{Page::map, MapFormat::html, false}));
    // Escaped, in the name or the value; the first of repeated names counts.
    EXPECT_EQ(route("GET", "/map?format=c%73v"), (Route{Page::map, MapFormat::csv, false}));
    EXPECT_EQ(route("GET", "/map?form%61t=md"), (Route{Page::map, MapFormat::markdown, false}));
    EXPECT_EQ(route("GET", "/map?format=csv&format=md"), (Route{Page::map, MapFormat::csv, false}));
    // Another parameter's malformed escape is not this one's business.
    EXPECT_EQ(route("GET", "/map?x=%zz&format=md"), (Route{Page::map, MapFormat::markdown, false}));

    EXPECT_EQ(route("GET", "/map?format=bad").error(),
              (Refusal{400, "format: 'bad' is not html, csv or md"}));
    EXPECT_EQ(route("GET", "/map?format=").error(),
              (Refusal{400, "format: '' is not html, csv or md"}));
    EXPECT_EQ(route("GET", "/map?format=CSV").error().status, 400U);
    EXPECT_EQ(route("GET", "/map?format=%zz").error(),
              (Refusal{400, "format: a malformed %-escape; use html, csv or md"}));
    EXPECT_EQ(route("GET", "/map?format=%4").error().status, 400U);
    EXPECT_EQ(route("GET", "/map?format=csv%").error().status, 400U);
    // The method before the query: a POST with a bad format is still refused as a POST.
    EXPECT_EQ(status("POST", "/map?format=bad"), 405U);
}

// --- route() with the Host: DNS rebinding -----------------------------------------------------

const std::vector<std::string> names{"box7", "gateway.plant.example"};

unsigned host_status(std::string_view host, unsigned version = 11, std::size_t hosts = 1) {
    const auto routed = route(Request{"GET", "/api/v1/state", version, hosts, host}, names);
    return routed ? 200 : routed.error().status;
}

TEST(HttpHost, IpLiteralsLocalhostAndTheNamesAreServedWithOrWithoutAPort) {
    for (const auto host : {"127.0.0.1", "127.0.0.1:8502", "10.1.2.3:80", "[::1]", "[::1]:8502",
                            "[fe80::1]:", "[::ffff:127.0.0.1]:8502", "localhost", "localhost:8502",
                            "LocalHost", "localhost.", "box7", "BOX7:8502", "gateway.plant.example",
                            "Gateway.Plant.Example.:443"}) {
        SCOPED_TRACE(host);
        EXPECT_EQ(host_status(host), 200U);
        EXPECT_EQ(route(Request{"GET", "/metrics", 11, 1, host}, names),
                  (Route{Page::metrics, MapFormat::html, false}));
    }
}

TEST(HttpHost, AnyOtherNameIs421WhateverThePageOrMethod) {
    for (const auto host : {"evil.example", "evil.example:8502", "box7.evil.example", "box", "",
                            "localhost.evil.example", "127.0.0.1.evil.example", "1.2.3",
                            "0x7f000001", "user@localhost", "2130706433"}) {
        SCOPED_TRACE(host);
        const auto routed = route(Request{"GET", "/api/v1/state", 11, 1, host}, names);
        ASSERT_FALSE(routed);
        EXPECT_EQ(routed.error().status, 421U);
        EXPECT_NE(routed.error().message.find("http.server_names"), std::string::npos);
        EXPECT_EQ(route(Request{"POST", "/nowhere", 11, 1, host}, names).error().status, 421U);
    }
    // Without names of its own, only IP literals and localhost.
    EXPECT_FALSE(route(Request{"GET", "/", 11, 1, "box7"}, {}));
    EXPECT_TRUE(route(Request{"GET", "/", 11, 1, "[::1]:1"}, {}));
}

TEST(HttpHost, MalformedOrSeveralHostsAre400) {
    for (const auto host :
         {"127.0.0.1:80x", "localhost:-1", "evil.example:", "[::1", "[::1]x", "[::1]:8502:1",
          "[evil.example]", "[v1.x]", "::1", "[fe80::1%eth0]", "localhost:80:80"}) {
        SCOPED_TRACE(host);
        const auto status = host_status(host);
        // "evil.example:" has an empty port, which RFC 3986 allows: a name this server lacks.
        EXPECT_EQ(status, std::string_view(host) == "evil.example:" ? 421U : 400U);
    }
    EXPECT_EQ(route(Request{"GET", "/", 11, 2, "127.0.0.1"}, names).error(),
              (Refusal{400, "more than one Host header"}));
}

// RFC 9112 §3.2: HTTP/1.1 requires a Host. HTTP/1.0 without one is served: browsers always send
// a Host, so such a request cannot be a DNS rebinding; with one, it is checked as any other.
TEST(HttpHost, NoHostIs400ForHttp11AndServedForHttp10) {
    EXPECT_EQ(route(Request{"GET", "/metrics", 11, 0, ""}, names).error(),
              (Refusal{400, "HTTP/1.1 requires a Host header"}));
    EXPECT_EQ(route(Request{"GET", "/metrics", 10, 0, ""}, names),
              (Route{Page::metrics, MapFormat::html, false}));
    EXPECT_EQ(host_status("evil.example", 10), 421U);
    EXPECT_EQ(host_status("127.0.0.1", 10), 200U);
}

// The Host first: a misdirected request is not told which pages or methods there are.
TEST(HttpHost, TheHostIsDecidedBeforeThePathAndTheMethod) {
    EXPECT_EQ(route(Request{"GET", "/nowhere", 11, 1, "localhost"}, names).error().status, 404U);
    EXPECT_EQ(route(Request{"PUT", "/metrics", 11, 1, "localhost"}, names).error().status, 405U);
    EXPECT_EQ(route(Request{"GET", "*", 11, 1, "evil.example"}, names).error().status, 421U);
}

// --- query_value() ---------------------------------------------------------------------------

std::optional<std::string> value_of(std::string_view query, std::string_view name) {
    auto value = query_value(query, name);
    EXPECT_TRUE(value) << query;
    return value ? *value : std::nullopt;
}

TEST(QueryValue, DecodesPlusAndPercentEscapes) {
    EXPECT_EQ(value_of("q=a+b", "q"), "a b");
    EXPECT_EQ(value_of("q=a%20b", "q"), "a b");
    EXPECT_EQ(value_of("q=a%2Bb%2b", "q"), "a+b+");
    EXPECT_EQ(value_of("q=%41%7e", "q"), "A~");
    EXPECT_EQ(value_of("q=%00", "q"), "\0"s);
    EXPECT_EQ(value_of("q=a=b", "q"), "a=b");  // the first '=' separates
    EXPECT_EQ(value_of("my+key=1", "my key"), "1");
}

TEST(QueryValue, FirstOfRepeatedNamesEmptyAndAbsentValues) {
    EXPECT_EQ(value_of("a=1&a=2", "a"), "1");
    EXPECT_EQ(value_of("b=0&a=&a=2", "a"), "");
    EXPECT_EQ(value_of("a", "a"), "");
    EXPECT_EQ(value_of("x=1&&a=3&", "a"), "3");
    EXPECT_EQ(value_of("b=1", "a"), std::nullopt);
    EXPECT_EQ(value_of("", "a"), std::nullopt);
    EXPECT_EQ(value_of("A=1", "a"), std::nullopt);  // names are case-sensitive
    EXPECT_EQ(value_of("%zz=1&a=2", "a"), "2");     // a name that does not decode is not `a`
}

TEST(QueryValue, MalformedEscapesOfTheValueAreErrors) {
    for (const auto query : {"a=%", "a=%4", "a=%zz", "a=%g0", "a=1%2", "a=%%41"}) {
        SCOPED_TRACE(query);
        const auto value = query_value(query, "a");
        ASSERT_FALSE(value);
        EXPECT_EQ(value.error(), "a: a malformed %-escape");
    }
    EXPECT_EQ(value_of("a=1&b=%", "a"), "1");  // b's escape is never decoded
}

// --- Exposition --------------------------------------------------------------------------------

TEST(Exposition, FamilyHeaderAndSamples) {
    Exposition e;
    e.family("ioportd_link_up", "gauge", "1 when the link's port is open");
    e.sample("ioportd_link_up", {{"link", "hub0"}}, 1);
    e.sample("ioportd_link_up", {{"link", "hub1"}}, 0);
    e.family("ioportd_modbus_connections", "gauge", "Open Modbus TCP connections");
    e.sample("ioportd_modbus_connections", {}, std::uint64_t{18446744073709551615ULL});
    e.sample("ioportd_x", {{"a", "1"}, {"b", ""}}, -3);  // a negative count is 0
    EXPECT_EQ(e.take(),
              "# HELP ioportd_link_up 1 when the link's port is open\n"
              "# TYPE ioportd_link_up gauge\n"
              "ioportd_link_up{link=\"hub0\"} 1\n"
              "ioportd_link_up{link=\"hub1\"} 0\n"
              "# HELP ioportd_modbus_connections Open Modbus TCP connections\n"
              "# TYPE ioportd_modbus_connections gauge\n"
              "ioportd_modbus_connections 18446744073709551615\n"
              "ioportd_x{a=\"1\",b=\"\"} 0\n");
}

TEST(Exposition, HelpEscapesBackslashAndNewlineOnly) {
    Exposition e;
    e.family("m", "counter", "a \\ b\nc \"d\"");
    EXPECT_EQ(e.take(), "# HELP m a \\\\ b\\nc \"d\"\n# TYPE m counter\n");
}

TEST(Exposition, LabelValuesEscapeBackslashQuoteAndNewline) {
    Exposition e;
    e.sample("m", {{"module", "a\\b\"c\nd\re\tf"}}, 2);
    EXPECT_EQ(e.take(), "m{module=\"a\\\\b\\\"c\\nd\re\tf\"} 2\n");
    std::string out;
    append_escaped_label(out, "\\\"\n");
    EXPECT_EQ(out, "\\\\\\\"\\n");
}

TEST(Exposition, DoublesNaNAndInfinities) {
    Exposition e;
    e.sample("m", {}, std::numeric_limits<double>::quiet_NaN());
    e.sample("m", {}, std::numeric_limits<double>::infinity());
    e.sample("m", {}, -std::numeric_limits<double>::infinity());
    e.sample("m", {}, 0.25);
    e.sample("m", {}, 3.0);
    e.sample("m", {}, 0.1);
    e.sample("m", {}, -2.5e-7);
    e.sample("m", {}, 1e21);
    EXPECT_EQ(e.take(), "m NaN\nm +Inf\nm -Inf\nm 0.25\nm 3\nm 0.1\nm -2.5e-07\nm 1e+21\n");
}

// --- Json --------------------------------------------------------------------------------------

TEST(Json, NestingPutsCommasBetweenValuesOnly) {
    Json json;
    json.begin_object()
        .member("a", 1)
        .member("b", true)
        .key("c")
        .begin_array()
        .value(1)
        .value("x")
        .null()
        .begin_array()
        .end_array()
        .begin_object()
        .end_object()
        .end_array()
        .key("d")
        .begin_object()
        .member("e", false)
        .key("f")
        .begin_array()
        .begin_array()
        .value(std::int64_t{-5})
        .value(std::uint64_t{18446744073709551615ULL})
        .end_array()
        .begin_array()
        .end_array()
        .end_array()
        .end_object()
        .member("g", "")
        .end_object();
    EXPECT_EQ(
        json.take(),
        R"({"a":1,"b":true,"c":[1,"x",null,[],{}],"d":{"e":false,"f":[[-5,18446744073709551615],[]]},"g":""})");
}

TEST(Json, TopLevelArrayOfObjects) {
    Json json;
    json.begin_array().begin_object().end_object().begin_object().member("k", 0).end_object();
    json.end_array();
    EXPECT_EQ(json.take(), R"([{},{"k":0}])");
}

TEST(Json, StringsEscapeQuotesBackslashesAndControlCharacters) {
    Json json;
    json.begin_array().value("\"\\\n\r\t\b\f"s).value("\x01\x1f\x7f/é\0z"s).end_array();
    EXPECT_EQ(json.take(),
              "[\"\\\"\\\\\\n\\r\\t\\u0008\\u000c\",\"\\u0001\\u001f\\u007f/é\\u0000z\"]");
    Json keys;
    keys.begin_object().member("a\"b", "c").end_object();
    EXPECT_EQ(keys.take(), R"({"a\"b":"c"})");
}

// Names and messages from the network (a DCMD's metric name in an event, say) may be any bytes:
// the document stays valid JSON, each byte that begins no UTF-8 sequence one U+FFFD (issue 23).
TEST(Json, InvalidUtf8BecomesTheReplacementCharacter) {
    const auto string = [](std::string_view text) {
        std::string out;
        append_json_string(out, text);
        return out;
    };
    // valid UTF-8 of every length stays as it is
    EXPECT_EQ(string("é€😀\u2028"), "\"é€😀\u2028\"");
    EXPECT_EQ(string("a\xFF"
                     "b"),
              "\"a\\ufffd"
              "b\"");                                                // never a lead byte
    EXPECT_EQ(string("\x80"), "\"\\ufffd\"");                        // a stray continuation
    EXPECT_EQ(string("\xC3"), "\"\\ufffd\"");                        // cut at the end
    EXPECT_EQ(string("\xE2\x82z"), "\"\\ufffd\\ufffdz\"");           // cut before z
    EXPECT_EQ(string("\xC0\xAF"), "\"\\ufffd\\ufffd\"");             // overlong '/'
    EXPECT_EQ(string("\xE0\x80\xAF"), "\"\\ufffd\\ufffd\\ufffd\"");  // overlong, 3 bytes
    EXPECT_EQ(string("\xED\xA0\x80"), "\"\\ufffd\\ufffd\\ufffd\"");  // a surrogate
    EXPECT_EQ(string("\xF4\x90\x80\x80"), "\"\\ufffd\\ufffd\\ufffd\\ufffd\"");  // past U+10FFFF
    EXPECT_EQ(string("\xF4\x8F\xBF\xBF"), "\"\xF4\x8F\xBF\xBF\"");              // U+10FFFF itself
    EXPECT_EQ(string("x\x7Fy\n"), "\"x\\u007fy\\n\"");
}

TEST(Json, NonFiniteNumbersAreNull) {
    Json json;
    json.begin_array()
        .value(std::numeric_limits<double>::quiet_NaN())
        .value(std::numeric_limits<double>::infinity())
        .value(-std::numeric_limits<float>::infinity())
        .value(std::numeric_limits<float>::quiet_NaN())
        .value(0.0)
        .end_array();
    EXPECT_EQ(json.take(), "[null,null,null,null,0]");
}

TEST(Json, NumbersInTheirShortestForm) {
    Json json;
    json.begin_array()
        .value(0.1f)
        .value(1.0f / 3.0f)
        .value(100.0f)
        .value(16777216.0f)
        .value(-1.5f)
        .value(0.1)
        .value(1.0 / 3.0)
        .value(2.0)
        .value(1e21)
        .value(1e-7f)
        .end_array();
    // A float is written as the float it is (0.1f is not 0.10000000149011612), so that a reader
    // parsing it as a double gets the float's value back.
    EXPECT_EQ(json.take(),
              "[0.1,0.33333334,100,16777216,-1.5,0.1,0.3333333333333333,2,1e+21,1e-07]");
}

// Found by fuzz/http_route.cpp: fmt 9.1's "{}", as clang 14 compiles its header code, wrote a
// subnormal double to one digit ("8e-309" for 7.6485216289552275e-309), which does not read back.
// g++ builds were right; the writers now use std::to_chars, exact whatever the compiler.
TEST(Json, SubnormalNumbersReadBackExactly) {
    const std::array<double, 4> doubles{7.6485216289552275e-309, 5e-324, -2.225073858507201e-308,
                                        std::numeric_limits<double>::denorm_min() * 3};
    Json json;
    json.begin_array();
    for (const double d : doubles)
        json.value(d);
    json.value(1e-40f).value(std::numeric_limits<float>::denorm_min()).end_array();
    const auto text = json.take();
    EXPECT_EQ(text, "[7.64852162895523e-309,5e-324,-2.225073858507201e-308,1.5e-323,1e-40,1e-45]");
    // And each reads back as itself.
    const char* at = text.c_str() + 1;
    for (const double d : doubles) {
        char* end = nullptr;
        EXPECT_EQ(std::strtod(at, &end), d);
        at = end + 1;
    }
    char* end = nullptr;
    EXPECT_EQ(std::strtof(at, &end), 1e-40f);
}

TEST(Exposition, SubnormalValuesReadBackExactly) {
    Exposition e;
    e.sample("m", {}, 7.6485216289552275e-309);
    EXPECT_EQ(e.take(), "m 7.64852162895523e-309\n");
}

// --- Histogram -------------------------------------------------------------------------------

TEST(Histogram, CumulativeBucketsWithAValueOnABoundInIt) {
    static constexpr std::array<double, 3> bounds{0.001, 0.01, 0.1};
    Histogram h(bounds);
    EXPECT_EQ(h.count(), 0U);
    EXPECT_EQ(h.cumulative(2), 0U);
    h.observe(0.001);  // le="0.001": at or under the bound
    h.observe(0.0005);
    h.observe(0.005);
    h.observe(0.1);
    h.observe(0.10001);
    h.observe(5);
    ASSERT_EQ(h.bounds().size(), 3U);
    EXPECT_EQ(h.cumulative(0), 2U);
    EXPECT_EQ(h.cumulative(1), 3U);
    EXPECT_EQ(h.cumulative(2), 4U);
    // +Inf is the count: everything observed, the two over the last bound included.
    EXPECT_EQ(h.count(), 6U);
    EXPECT_DOUBLE_EQ(h.sum(), 0.001 + 0.0005 + 0.005 + 0.1 + 0.10001 + 5);
}

// --- Trend -----------------------------------------------------------------------------------

std::chrono::system_clock::time_point unix_seconds(std::int64_t s) {
    return std::chrono::system_clock::time_point(std::chrono::seconds(s));
}

TEST(Trend, ReadingsOfOneIntervalShareItsPointTheLastOneWins) {
    Trend trend;
    EXPECT_EQ(trend.size(), 0U);
    trend.add(unix_seconds(1'000'001), {1, 2, 3});
    trend.add(unix_seconds(1'000'004), {4, 5, 6});
    ASSERT_EQ(trend.size(), 1U);
    EXPECT_EQ(trend[0].time, 1'000'000);  // the start of its interval
    EXPECT_EQ(trend[0].raw, (std::array<std::uint16_t, 3>{4, 5, 6}));
    trend.add(unix_seconds(1'000'005), {7, 8, 9});
    ASSERT_EQ(trend.size(), 2U);
    EXPECT_EQ(trend[1].time, 1'000'005);
    EXPECT_EQ(trend[1].raw, (std::array<std::uint16_t, 3>{7, 8, 9}));
    // An interval skipped (no good reading) leaves no point.
    trend.add(unix_seconds(1'000'017), {1, 1, 1});
    ASSERT_EQ(trend.size(), 3U);
    EXPECT_EQ(trend[2].time, 1'000'015);
}

TEST(Trend, AfterWrappingKeepsTheNewest120InOrder) {
    Trend trend;
    const std::int64_t t0 = 1'700'000'000;
    constexpr std::int64_t step = 5;  // Trend::interval, in seconds
    constexpr int added = 2 * static_cast<int>(Trend::capacity) + 7;
    for (int i = 0; i < added; ++i) {
        const auto word = static_cast<std::uint16_t>(i);
        trend.add(unix_seconds(t0 + step * i), {word, 0, 0});
        trend.add(unix_seconds(t0 + step * i + 3), {word, 1, 0});  // same interval: overwrites
    }
    ASSERT_EQ(trend.size(), Trend::capacity);
    for (std::size_t i = 0; i < Trend::capacity; ++i) {
        const auto n = static_cast<int>(added - Trend::capacity + i);
        ASSERT_EQ(trend[i].time, t0 + step * n) << i;
        ASSERT_EQ(trend[i].raw, (std::array<std::uint16_t, 3>{static_cast<std::uint16_t>(n), 1, 0}))
            << i;
    }
    // The newest point still takes its interval's later readings after the wrap.
    trend.add(unix_seconds(t0 + step * (added - 1) + 4), {9, 9, 9});
    EXPECT_EQ(trend.size(), Trend::capacity);
    EXPECT_EQ(trend[Trend::capacity - 1].raw, (std::array<std::uint16_t, 3>{9, 9, 9}));
    EXPECT_EQ(trend[0].time, t0 + step * (added - static_cast<int>(Trend::capacity)));
}

// --- process_stats ---------------------------------------------------------------------------

// /proc/PID/stat as the kernel writes it (proc(5)), with fields 14 utime, 15 stime, 22 starttime
// and 24 rss set; every other field a distinct number that must not be taken for them.
std::string proc_stat(std::string_view comm) {
    return fmt::format(
        "4242 ({}) S 1 4242 4242 0 -1 4194560 1500 0 3 0 250 50 7 8 20 0 3 0 1000 "
        "27262976 2048 18446744073709551615 1 1 0 0 0 0 0 4096 0 0 0 17 1 0 0 0 0 0 0 0 0 0 0 0 "
        "0 0\n",
        comm);
}

TEST(ProcessStats, ParsesTimesAndMemoryAfterTheCommand) {
    for (const auto comm : {"ioportd", "io portd", "a) S 1 2 3 (b", ")", "x)) (y", "(", ""}) {
        SCOPED_TRACE(comm);
        const auto stats = parse_proc_stat(proc_stat(comm), 100, 4096, 1'700'000'000.0);
        ASSERT_TRUE(stats);
        EXPECT_DOUBLE_EQ(stats->cpu_seconds, 3.0);  // (250 + 50) / 100
        EXPECT_EQ(stats->resident_bytes, 2048U * 4096U);
        EXPECT_DOUBLE_EQ(stats->start_time_seconds, 1'700'000'010.0);  // boot + 1000 / 100
        EXPECT_EQ(stats->open_fds, 0U);
    }
}

TEST(ProcessStats, MalformedTextIsRefused) {
    const auto parse = [](std::string_view text) {
        return parse_proc_stat(text, 100, 4096, 0).has_value();
    };
    EXPECT_FALSE(parse(""));
    EXPECT_FALSE(parse("4242 ioportd S 1 2 3"));  // no parentheses
    EXPECT_FALSE(parse("4242 (ioportd) S 1 4242 4242 0 -1 4194560 1500 0 3 0 250 50 7 8 20"));
    EXPECT_FALSE(parse("4242 (ioportd)"));
    auto text = proc_stat("ioportd");
    EXPECT_FALSE(parse(text.replace(text.find(" 250 "), 5, " 2x0 ")));
    text = proc_stat("ioportd");
    EXPECT_FALSE(parse(text.replace(text.find(" 2048 "), 6, " -2048 ")));
    EXPECT_FALSE(parse_proc_stat(proc_stat("ioportd"), 0, 4096, 0));  // no clock ticks
    // The fields up to rss are all it needs.
    EXPECT_TRUE(
        parse("4242 (x) S 1 4242 4242 0 -1 4194560 1500 0 3 0 250 50 7 8 20 0 3 0 1000 "
              "27262976 2048"));
}

}  // namespace
}  // namespace ioport::daemon
