// Sparkplug B 3.0 (gateway.md §5.5) as pure functions: topics, payload bytes on the protobuf
// wire, the metrics of each module and their values, and DCMD metrics as gateway writes.
#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "protocol/sparkplug.hpp"

namespace ioport::sparkplug {
namespace {

using Bytes = std::vector<std::uint8_t>;

TEST(SparkplugTopic, NodeDeviceAndStateTopics) {
    EXPECT_EQ(topic("plant1", MessageType::nbirth, "box7"), "spBv1.0/plant1/NBIRTH/box7");
    EXPECT_EQ(topic("plant1", MessageType::ddata, "box7", "hub0.dim16.0"),
              "spBv1.0/plant1/DDATA/box7/hub0.dim16.0");
    EXPECT_EQ(state_topic("scada"), "spBv1.0/STATE/scada");
    EXPECT_EQ(parse_topic("spBv1.0/plant1/DCMD/box7/hub0.dom16.1"),
              (Topic{MessageType::dcmd, "plant1", "box7", "hub0.dom16.1"}));
    EXPECT_EQ(parse_topic("spBv1.0/plant1/NCMD/box7"),
              (Topic{MessageType::ncmd, "plant1", "box7", ""}));
    EXPECT_EQ(parse_topic("spBv1.0/STATE/scada"), (Topic{MessageType::state, "", "scada", ""}));
}

TEST(SparkplugTopic, WhatIsNotASparkplugTopic) {
    for (const char* text :
         {"", "spBv1.0", "spAv1.0/g/NCMD/n", "spBv1.0/g/NCMD", "spBv1.0/g/NCMD/n/device",
          "spBv1.0/g/DCMD/n", "spBv1.0/g/DCMD/n/", "spBv1.0//NCMD/n", "spBv1.0/g/NCMD/",
          "spBv1.0/g/NOPE/n", "spBv1.0/STATE", "spBv1.0/STATE/", "spBv1.0/STATE/a/b",
          "spBv1.0/g/DCMD/n/d/e"})
        EXPECT_FALSE(parse_topic(text)) << text;
}

TEST(SparkplugTopic, IdsMustNotBreakTopics) {
    EXPECT_TRUE(check_id("plant-1.box_7"));
    EXPECT_FALSE(check_id(""));
    for (const char* bad : {"a/b", "a+", "#", "a\nb"}) {
        const auto checked = check_id(bad);
        ASSERT_FALSE(checked) << bad;
        EXPECT_FALSE(checked.error().message.empty());
    }
}

// The bytes a Sparkplug host decodes: fields in number order, each a tag (field << 3 | wire
// type) then a varint or a length and bytes.
TEST(SparkplugPayload, EncodesToTheProtobufWireFormat) {
    const Payload payload{1, 0, {Metric{"a", 1, std::nullopt, 11, Value(true)}}};
    const Bytes expected{
        0x08, 0x01,       // 1 timestamp: 1
        0x12, 0x09,       // 2 metrics: 9 bytes
        0x0A, 0x01, 'a',  //   1 name: "a"
        0x10, 0x01,       //   2 alias: 1
        0x20, 0x0B,       //   4 datatype: 11 Boolean
        0x70, 0x01,       //   14 boolean_value: true
        0x18, 0x00,       // 3 seq: 0
    };
    EXPECT_EQ(encode(payload), expected);
}

TEST(SparkplugPayload, IntegersGoWhereTheirWidthSays) {
    const Payload payload{0,
                          std::nullopt,
                          {Metric{"", 2, std::nullopt, 6, Value(std::uint64_t{0xFFFF})},
                           Metric{"", 3, std::nullopt, 4, Value(std::uint64_t{300})},
                           Metric{"", 4, std::nullopt, 6, std::nullopt}}};
    const Bytes expected{
        0x08, 0x00,              // 1 timestamp: 0
        0x12, 0x08,              // 2 metrics: 8 bytes
        0x10, 0x02,              //   2 alias: 2
        0x20, 0x06,              //   4 datatype: 6 UInt16
        0x50, 0xFF, 0xFF, 0x03,  //   10 int_value: 65535
        0x12, 0x07,              // 2 metrics: 7 bytes
        0x10, 0x03,              //   2 alias: 3
        0x20, 0x04,              //   4 datatype: 4 Int64
        0x58, 0xAC, 0x02,        //   11 long_value: 300
        0x12, 0x06,              // 2 metrics: 6 bytes
        0x10, 0x04,              //   2 alias: 4
        0x20, 0x06,              //   4 datatype: 6 UInt16
        0x38, 0x01,              //   7 is_null: true
    };
    EXPECT_EQ(encode(payload), expected);
}

TEST(SparkplugPayload, DataLeavesTheDatatypeToTheBirth) {
    // The datatype still chooses the field: UInt64 in long_value, UInt16 in int_value.
    const Payload payload{0,
                          1,
                          {Metric{"", 2, std::nullopt, 8, Value(std::uint64_t{300})},
                           Metric{"", 3, std::nullopt, 6, Value(std::uint64_t{300})}}};
    const Bytes expected{
        0x08, 0x00,        // 1 timestamp: 0
        0x12, 0x05,        // 2 metrics: 5 bytes
        0x10, 0x02,        //   2 alias: 2
        0x58, 0xAC, 0x02,  //   11 long_value: 300
        0x12, 0x05,        // 2 metrics: 5 bytes
        0x10, 0x03,        //   2 alias: 3
        0x50, 0xAC, 0x02,  //   10 int_value: 300
        0x18, 0x01,        // 3 seq: 1
    };
    EXPECT_EQ(encode(payload, Datatypes::left_out), expected);
}

TEST(SparkplugPayload, DecodesWhatItEncodes) {
    const Payload payload{1796183655123,
                          255,
                          {Metric{"bdSeq", std::nullopt, 17, 4, Value(std::uint64_t{7})},
                           Metric{"value/0", 12, 17, 9, Value(20.154116f)},
                           Metric{"colour", 13, std::nullopt, 5, Value(std::uint64_t{3})},
                           Metric{"in/3", 14, std::nullopt, 11, Value(false)},
                           Metric{"note", std::nullopt, std::nullopt, 12, Value(std::string("ok"))},
                           Metric{"count", 15, std::nullopt, 6, std::nullopt}}};
    const auto decoded = decode(encode(payload));
    ASSERT_TRUE(decoded) << decoded.error().message;
    EXPECT_EQ(*decoded, payload);
}

TEST(SparkplugPayload, PropertiesAreTypedAndDecodeAsTheyWereSent) {
    Payload payload{1, 3, {Metric{"value/0", 12, 17, 9, Value(14.25f)}}};
    payload.metrics[0].properties = {{"engUnit", std::string("°C")},
                                     {"engLow", -20.0},
                                     {"engHigh", 150.0},
                                     {"documentation", std::string("boiler 1: supply")}};
    const auto bytes = encode(payload);
    const auto decoded = decode(bytes);
    ASSERT_TRUE(decoded) << decoded.error().message;
    EXPECT_EQ(*decoded, payload);
    // On the wire (Sparkplug 3.0 §6.4.18): metric field 9, a PropertySet of keys (1) and values
    // (2), each value with its type (1): Double 10 in double_value (6), String 12 in string_value
    // (8). engLow: type 10, then -20.0 as a little-endian double.
    const Bytes eng_low{0x12, 0x0B, 0x08, 0x0A, 0x31, 0, 0, 0, 0, 0, 0, 0x34, 0xC0};
    EXPECT_NE(std::search(bytes.begin(), bytes.end(), eng_low.begin(), eng_low.end()), bytes.end());
    const Bytes unit{0x12, 0x07, 0x08, 0x0C, 0x42, 0x03, 0xC2, 0xB0, 'C'};
    EXPECT_NE(std::search(bytes.begin(), bytes.end(), unit.begin(), unit.end()), bytes.end());
}

TEST(SparkplugPayload, AHistoricalMetricSaysSo) {
    Metric metric{"in/0", std::nullopt, 5, 11, Value(true)};
    metric.is_historical = true;
    const Bytes expected{
        0x08, 0x07,                      // 1 timestamp: 7
        0x12, 0x0E,                      // 2 metrics: 14 bytes
        0x0A, 0x04, 'i', 'n', '/', '0',  //   1 name: "in/0"
        0x18, 0x05,                      //   3 timestamp: 5
        0x20, 0x0B,                      //   4 datatype: 11 Boolean
        0x28, 0x01,                      //   5 is_historical: true
        0x70, 0x01,                      //   14 boolean_value: true
    };
    const Payload payload{7, std::nullopt, {metric}};
    EXPECT_EQ(encode(payload), expected);
    EXPECT_EQ(decode(expected).value(), payload);
}

TEST(SparkplugStored, ARecordBodyIsTheDeviceAndThePayload) {
    const StoredData data{
        "hub0.dim16.0",
        Payload{7, std::nullopt, {Metric{"in/0", std::nullopt, 5, 11, Value(true)}}}};
    const auto bytes = encode_stored(data);
    const Bytes header{0x01, 12, 0x00};  // version 1, device id of 12 bytes
    ASSERT_GT(bytes.size(), header.size() + 12);
    EXPECT_EQ(Bytes(bytes.begin(), bytes.begin() + 3), header);
    EXPECT_EQ(std::string(bytes.begin() + 3, bytes.begin() + 15), "hub0.dim16.0");
    EXPECT_EQ(Bytes(bytes.begin() + 15, bytes.end()), encode(data.payload));
    EXPECT_EQ(decode_stored(bytes).value(), data);
}

TEST(SparkplugStored, WhatIsNotABodyIsAnError) {
    for (const Bytes& bytes : {Bytes{}, Bytes{0x02, 0x00, 0x00}, Bytes{0x01, 0x05, 0x00, 'h'},
                               Bytes{0x01, 0x01, 0x00, 'h', 0x12, 0x40}}) {
        const auto decoded = decode_stored(bytes);
        ASSERT_FALSE(decoded) << bytes.size();
        EXPECT_EQ(decoded.error().code, Errc::malformed);
    }
}

TEST(SparkplugPayload, GarbageIsAnErrorNotACrash) {
    const Bytes garbage{0x12, 0x40, 0x0A};  // a metric of 64 bytes, three there
    const auto decoded = decode(garbage);
    ASSERT_FALSE(decoded);
    EXPECT_EQ(decoded.error().code, Errc::malformed);
    EXPECT_TRUE(decode(Bytes{}));  // the empty payload is a valid, empty message
}

// The error code of a STATE refused; nullopt when it was taken.
std::optional<Errc> refused(std::string_view json) {
    const auto state = parse_state(json);
    if (state) return std::nullopt;
    return state.error().code;
}

TEST(SparkplugState, TheStateMessageOfSparkplug3) {
    EXPECT_EQ(*parse_state(R"({"online":true,"timestamp":1})"), (HostState{true, 1}));
    EXPECT_EQ(*parse_state(R"({ "timestamp" : 1796183655123, "online" : false })"),
              (HostState{false, 1796183655123}));
    EXPECT_EQ(refused(R"({"online": "yes"})"), Errc::malformed);
    EXPECT_EQ(refused("ONLINE"), Errc::malformed);  // Sparkplug 2's plain text
    EXPECT_EQ(refused(""), Errc::malformed);
    // A member of a nested object, or the key in a string, is not the state's own.
    EXPECT_EQ(refused(R"({"host": {"online": true}})"), Errc::malformed);
    EXPECT_EQ(*parse_state(R"({"note": "\"online\": true", "online": false})"),
              (HostState{false, 0}));
    EXPECT_EQ(refused(R"({"online": "true"})"), Errc::malformed);
    EXPECT_EQ(state_json(true, 5), R"({"online":true,"timestamp":5})");
    // The timestamp, when there, is an unquoted whole number: else not a STATE.
    EXPECT_EQ(*parse_state(R"({"online": true})"), (HostState{true, 0}));
    EXPECT_EQ(*parse_state(R"({"online": true, "timestamp": 18446744073709551615})"),
              (HostState{true, 18446744073709551615U}));
    for (const auto* json :
         {R"({"online": true, "timestamp": "5"})", R"({"online": true, "timestamp": -5})",
          R"({"online": true, "timestamp": 5.5})", R"({"online": true, "timestamp": [5]})",
          R"({"online": true, "timestamp": 5e3})", R"({"online": true, "timestamp": null})",
          R"({"online": true, "timestamp": 18446744073709551616})"})
        EXPECT_EQ(refused(json), Errc::malformed) << json;
}

TEST(SparkplugState, JsonAndNothingElse) {
    // yaml-cpp read STATEs once: YAML's own forms are not JSON, and are refused.
    for (const auto* json :
         {R"({online: true})", R"({"online": yes})", "online: true", R"({"online": true,})",
          R"({"online": true} // comment)", R"({'online': true})", R"(["online", true])", "true"})
        EXPECT_EQ(refused(json), Errc::malformed) << json;
    // Nesting a parser with a stack of its own reads without overflowing ours.
    EXPECT_EQ(refused(std::string(max_state_bytes, '[')), Errc::malformed);
    // A number beyond a double's range: the parser threw out_of_range, not parse_error, and
    // any client of the broker that published it as the host's STATE ended the daemon.
    EXPECT_EQ(refused(R"({"online": true, "timestamp": 1e400})"), Errc::malformed);
    EXPECT_EQ(refused(R"({"online": true, "x": -1e309})"), Errc::malformed);
    EXPECT_EQ(parse_state(R"({"online": true, "x": 1e400})").error().message,
              "not JSON: number overflow parsing '1e400'");
}

TEST(SparkplugState, ALargeStateIsRefusedUnread) {
    // A STATE is a few dozen bytes; beyond the bound nothing is parsed (issue 37: a 2 MB STATE
    // took 1.05 s of the loop and 249 MB), so even a valid document that long is refused.
    std::string padded = R"({"online": true, "note": ")";
    padded += std::string(max_state_bytes, 'x') + R"("})";
    EXPECT_EQ(refused(padded), Errc::invalid_argument);
    EXPECT_EQ(parse_state(padded).error().message,
              fmt::format("{} bytes, more than the 1024 a STATE may have", padded.size()));
    std::string fits = R"({"online": true, "note": ")";
    fits += std::string(max_state_bytes - fits.size() - 2, 'x') + R"("})";
    ASSERT_EQ(fits.size(), max_state_bytes);
    EXPECT_TRUE(parse_state(fits));
}

TEST(SparkplugModule, DeviceIdsAsGatewayMdSays) {
    EXPECT_EQ(device_id("hub0", ModuleAddress{ModuleType::dim16, 0}), "hub0.dim16.0");
    EXPECT_EQ(device_id("hub0", ModuleAddress{ModuleType::mux8m, 7}), "hub0.mux8m.7");
    EXPECT_EQ(device_id("press", std::nullopt), "press.id2");
}

TEST(SparkplugModule, DeviceIdsWithAnotherSeparatorStayUnique) {
    // RabbitMQ turns the '.' of topics into '/' (issue 49): '_' keeps a device one level.
    EXPECT_EQ(device_id("hub0", ModuleAddress{ModuleType::dim16, 0}, '_'), "hub0_dim16_0");
    EXPECT_EQ(device_id("press", std::nullopt, '-'), "press-id2");
    // Links whose names hold the separator: still one id per device, as the last part is a
    // number or "id2" and no type's name holds a separator.
    for (const char separator : device_id_separators) {
        std::set<std::string> ids;
        std::size_t devices = 0;
        const std::string with = std::string("a") + separator;
        for (const std::string& link :
             {std::string("a"), with + "dim16", with + "dim16" + separator + "0", with + "id2",
              std::string("dim16")}) {
            for (const auto type : {ModuleType::dim16, ModuleType::dom16}) {
                for (const int number : {0, 1}) {
                    ids.insert(device_id(
                        link, ModuleAddress{type, static_cast<std::uint8_t>(number)}, separator));
                    ++devices;
                }
            }
            ids.insert(device_id(link, std::nullopt, separator));
            ++devices;
        }
        EXPECT_EQ(ids.size(), devices) << separator;
    }
}

TEST(SparkplugModule, EveryMetricOfEveryModule) {
    const auto dim = module_metrics(ModuleType::dim16);
    ASSERT_EQ(dim.size(), 17u);
    EXPECT_EQ(dim[0], (MetricSpec{"in/0", DataType::boolean, false}));
    EXPECT_EQ(dim[15], (MetricSpec{"in/15", DataType::boolean, false}));
    EXPECT_EQ(dim[16], (MetricSpec{"word", DataType::uint16, false}));
    const auto dom = module_metrics(ModuleType::dom16);
    ASSERT_EQ(dom.size(), 17u);
    EXPECT_EQ(dom[4], (MetricSpec{"out/4", DataType::boolean, true}));
    EXPECT_EQ(dom[16], (MetricSpec{"word", DataType::uint16, true}));
    const auto acm = module_metrics(ModuleType::acm3p);
    ASSERT_EQ(acm.size(), 6u);
    EXPECT_EQ(acm[2], (MetricSpec{"raw/2", DataType::uint16, false}));
    EXPECT_EQ(acm[3], (MetricSpec{"value/0", DataType::float32, false}));
    EXPECT_EQ(module_metrics(ModuleType::dcvim).size(), 2u);
    EXPECT_EQ(module_metrics(ModuleType::rgbdm),
              (std::vector<MetricSpec>{{"colour", DataType::uint8, true}}));
    EXPECT_EQ(
        module_metrics(ModuleType::mux8m),
        (std::vector<MetricSpec>{{"pos", DataType::uint8, true}, {"neg", DataType::uint8, true}}));
    EXPECT_EQ(module_metrics(std::nullopt),
              (std::vector<MetricSpec>{{"stop", DataType::boolean, false},
                                       {"count", DataType::uint16, false},
                                       {"reset", DataType::boolean, true}}));
}

TEST(SparkplugModule, MetricValuesAreThePointsValues) {
    EXPECT_EQ(metric_value(gateway::PointValue(true)), Value(true));
    EXPECT_EQ(metric_value(gateway::PointValue(std::uint64_t{42})), Value(std::uint64_t{42}));
    EXPECT_EQ(metric_value(gateway::PointValue(1.5F)), Value(1.5F));
}

TEST(SparkplugModule, BirthPropertiesNameUnitAndRange) {
    const ModuleAddress acm3p{ModuleType::acm3p, 0};
    auto tags = gateway::default_tags(acm3p);
    const auto plain = module_properties(acm3p, tags);
    ASSERT_EQ(plain.size(), 6u);
    EXPECT_TRUE(plain[0].empty());  // raw/0: nothing to say
    EXPECT_EQ(plain[3], (std::vector<Property>{
                            {"engUnit", std::string("%")}, {"engLow", 0.0}, {"engHigh", 100.0}}));

    tags.name = "boiler 1";
    tags.channels[0] = {"supply temperature", "°C", gateway::Scale{0, 100, -20, 150}, {-20, 150}};
    tags.channels[1].unit = "";
    const auto named = module_properties(acm3p, tags);
    EXPECT_EQ(
        named[0],
        (std::vector<Property>{{"documentation", std::string("boiler 1: supply temperature")}}));
    EXPECT_EQ(named[1], (std::vector<Property>{{"documentation", std::string("boiler 1")}}));
    EXPECT_EQ(named[3], (std::vector<Property>{
                            {"engUnit", std::string("°C")},
                            {"engLow", -20.0},
                            {"engHigh", 150.0},
                            {"documentation", std::string("boiler 1: supply temperature")}}));
    EXPECT_EQ(named[4], (std::vector<Property>{{"engLow", 0.0},
                                               {"engHigh", 100.0},
                                               {"documentation", std::string("boiler 1")}}));

    const ModuleAddress dim16{ModuleType::dim16, 2};
    auto inputs = gateway::default_tags(dim16);
    inputs.points[5] = "pump running";
    const auto points = module_properties(dim16, inputs);
    ASSERT_EQ(points.size(), 17u);
    EXPECT_EQ(points[5],
              (std::vector<Property>{{"documentation", std::string("dim16 2: pump running")}}));
    EXPECT_TRUE(points[4].empty());
    EXPECT_TRUE(points[16].empty());                                          // word
    EXPECT_EQ(module_properties(std::nullopt, gateway::no_tags).size(), 3u);  // the ID-2: none
    for (const auto& properties : module_properties(std::nullopt, gateway::no_tags))
        EXPECT_TRUE(properties.empty());
}

gateway::WritePlan planned(std::optional<ModuleAddress> module, std::string_view name,
                           const std::optional<Value>& value) {
    auto plan = plan_command(module, name, 0, value);
    EXPECT_TRUE(plan) << (plan ? "" : plan.error().message);
    return plan ? *plan : gateway::WritePlan{};
}

TEST(SparkplugCommand, WritesBecomeTheGatewaysOutputChanges) {
    const ModuleAddress dom{ModuleType::dom16, 1};
    EXPECT_EQ(planned(dom, "out/3", Value(true)).changes,
              (std::vector<gateway::OutputChange>{{dom, 0x0008, 0x0008}}));
    EXPECT_EQ(planned(dom, "out/15", Value(false)).changes,
              (std::vector<gateway::OutputChange>{{dom, 0x8000, 0x0000}}));
    EXPECT_EQ(planned(dom, "word", Value(std::uint64_t{0x1234})).changes,
              (std::vector<gateway::OutputChange>{{dom, 0xFFFF, 0x1234}}));
    const ModuleAddress rgb{ModuleType::rgbdm, 0};
    EXPECT_EQ(planned(rgb, "colour", Value(std::uint64_t{7})).changes,
              (std::vector<gateway::OutputChange>{{rgb, 0xFFFF, 7}}));
    const ModuleAddress mux{ModuleType::mux8m, 2};
    EXPECT_EQ(planned(mux, "pos", Value(std::uint64_t{3})).changes,
              (std::vector<gateway::OutputChange>{{mux, 0xFF00, 0x0300}}));
    EXPECT_EQ(planned(mux, "neg", Value(std::uint64_t{6})).changes,
              (std::vector<gateway::OutputChange>{{mux, 0x00FF, 0x0006}}));
    const auto reset = planned(std::nullopt, "reset", Value(true));
    EXPECT_TRUE(reset.reset_counter);
    EXPECT_TRUE(reset.changes.empty());
    EXPECT_FALSE(planned(std::nullopt, "reset", Value(false)).reset_counter);
}

TEST(SparkplugCommand, TheDeclaredDatatypeMustBeTheMetrics) {
    const ModuleAddress rgb{ModuleType::rgbdm, 0};
    EXPECT_TRUE(plan_command(rgb, "colour", 5, Value(std::uint64_t{3})));        // UInt8, as born
    const auto wider = plan_command(rgb, "colour", 8, Value(std::uint64_t{3}));  // UInt64
    ASSERT_FALSE(wider);
    EXPECT_NE(wider.error().message.find("declared datatype 8, but the metric is UInt8"),
              std::string::npos)
        << wider.error().message;
}

TEST(SparkplugCommand, RefusedNeverTruncated) {
    const ModuleAddress dom{ModuleType::dom16, 1};
    const ModuleAddress rgb{ModuleType::rgbdm, 0};
    const ModuleAddress mux{ModuleType::mux8m, 0};
    const ModuleAddress dim{ModuleType::dim16, 0};
    struct Case {
        std::optional<ModuleAddress> module;
        std::string name;
        std::optional<Value> value;
        std::string fragment;
    };
    for (const auto& c : std::vector<Case>{
             // The module's own rule, as for a Modbus write (validate_output_value).
             {rgb, "colour", Value(std::uint64_t{8}), "rgbdm colour 8 is out of range"},
             {mux, "pos", Value(std::uint64_t{8}), "mux8m value 0x0800 is out of range"},
             {mux, "neg", Value(std::uint64_t{255}), "mux8m value 0x00FF is out of range"},
             {rgb, "colour", Value(std::uint64_t{256}), "256 is over 255"},
             {dom, "word", Value(std::uint64_t{0x10000}), "65536 is over 65535"},
             {dom, "out/3", Value(std::uint64_t{1}), "expected Boolean"},
             {dom, "word", Value(true), "expected UInt16, got Boolean"},
             {dom, "word", Value(1.5f), "expected UInt16, got Float"},
             {dom, "word", std::nullopt, "null"},
             {dim, "in/0", Value(true), "read-only"},
             {dom, "out/16", Value(true), "no such metric"},
             {std::nullopt, "count", Value(std::uint64_t{0}), "read-only"},
             {std::nullopt, "reset", Value(std::string("yes")), "expected Boolean"}}) {
        const auto plan = plan_command(c.module, c.name, 0, c.value);
        ASSERT_FALSE(plan) << c.name;
        EXPECT_EQ(plan.error().code, Errc::invalid_argument);
        EXPECT_NE(plan.error().message.find(c.fragment), std::string::npos)
            << plan.error().message << " should contain " << c.fragment;
        EXPECT_NE(plan.error().message.find(c.name), std::string::npos) << plan.error().message;
    }
}

// --- The size of a command (gateway.md §5.5, issue 23) ------------------------------------------

Payload command_of(std::size_t metrics, const std::string& name = "out/0") {
    Payload payload{1796183655123, std::nullopt, {}};
    for (std::size_t i = 0; i < metrics; ++i)
        payload.metrics.push_back(Metric{name, std::nullopt, 17, 11, Value(true)});
    return payload;
}

TEST(SparkplugCommandSize, EachDeviceTakesAsManyMetricsAsItHasWritableOnes) {
    EXPECT_EQ(writable_metrics(ModuleType::dom16), 17u);  // out/0…out/15, word
    EXPECT_EQ(writable_metrics(ModuleType::rgbdm), 1u);
    EXPECT_EQ(writable_metrics(ModuleType::mux8m), 2u);
    EXPECT_EQ(writable_metrics(ModuleType::dim16), 0u);
    EXPECT_EQ(writable_metrics(ModuleType::acm3p), 0u);
    EXPECT_EQ(writable_metrics(std::nullopt), 1u);  // the ID-2's reset
}

TEST(SparkplugCommandSize, MetricsAreCountedWithoutDecoding) {
    for (const std::size_t n : {0u, 1u, 17u, 1000u}) {
        const auto counted = count_metrics(encode(command_of(n)));
        ASSERT_TRUE(counted) << counted.error().message;
        EXPECT_EQ(*counted, n);
    }
    // every wire type a payload's fields may have; a metric is field 2, length-delimited
    const Bytes fields{0x08, 0x96, 0x01,                      // 1 varint
                       0x12, 0x00,                            // 2: an empty metric
                       0x19, 1,    2,    3,   4, 5, 6, 7, 8,  // 3 fixed64
                       0x22, 0x02, 'i',  'd',                 // 4 bytes
                       0x35, 1,    2,    3,   4,              // 6 fixed32
                       0x10, 0x05,                            // 2 as a varint: not a metric
                       0x12, 0x02, 0x08, 0x01};               // 2: a metric
    EXPECT_EQ(count_metrics(fields), 2u);
    for (const auto& bad : {Bytes{0x12, 0x40, 0x0A},  // 64 bytes said, one there
                            Bytes{0x08},              // a varint cut
                            Bytes{0x19, 1, 2},        // a fixed64 cut
                            Bytes{0x0B, 0x0C},        // a group
                            Bytes{0x00, 0x00},        // field 0
                            Bytes(11, 0xFF)}) {       // a varint of 11 bytes
        const auto counted = count_metrics(bad);
        ASSERT_FALSE(counted);
        EXPECT_EQ(counted.error().code, Errc::malformed);
    }
}

TEST(SparkplugCommandSize, MoreMetricsThanTheDeviceWritesIsRefusedWhole) {
    const auto dom16 = writable_metrics(ModuleType::dom16);
    const auto fits = decode_command(encode(command_of(dom16)), dom16);
    ASSERT_TRUE(fits) << fits.error().message;
    EXPECT_EQ(fits->metrics.size(), dom16);
    // one more, each as small as a metric gets: refused by count
    const auto over = decode_command(encode(command_of(dom16 + 1)), dom16);
    ASSERT_FALSE(over);
    EXPECT_EQ(over.error().code, Errc::invalid_argument);
    EXPECT_NE(over.error().message.find("names 18 metrics, and the device has 17 writable"),
              std::string::npos)
        << over.error().message;
    // the issue's 1.1 MB DCMD of 100,000 out/0: refused by size, before anything is walked
    const auto flood = encode(command_of(100'000));
    const auto refused = decode_command(flood, dom16);
    ASSERT_FALSE(refused);
    EXPECT_EQ(refused.error().code, Errc::invalid_argument);
    EXPECT_NE(refused.error().message.find(fmt::format("{} bytes", flood.size())),
              std::string::npos)
        << refused.error().message;
    // a device with nothing to write takes no metric at all
    EXPECT_FALSE(decode_command(encode(command_of(1)), 0));
    EXPECT_TRUE(decode_command(encode(command_of(0)), 0));
    // garbage within the bounds stays malformed
    const auto garbage = decode_command(Bytes{0x12, 0x40, 0x0A}, dom16);
    ASSERT_FALSE(garbage);
    EXPECT_EQ(garbage.error().code, Errc::malformed);
}

TEST(SparkplugCommandSize, ABoundOfBytesLeavesRoomForLongNames) {
    // 17 metrics with names of 200 bytes: within max_command_bytes(17)
    const auto long_names = encode(command_of(17, std::string(200, 'x')));
    EXPECT_LE(long_names.size(), max_command_bytes(17));
    EXPECT_TRUE(decode_command(long_names, 17));
    EXPECT_FALSE(decode_command(Bytes(max_command_bytes(17) + 1, 0), 17));
}

// --- Templates (gateway.md §7.2) ---------------------------------------------------------------

// Sparkplug 3.0 §6.4.14 on the wire: the Template is metric field 18 (tag 0x92 0x01), holding
// version (1), member metrics (2), template_ref (4) and is_definition (5).
TEST(SparkplugTemplate, ADefinitionOnTheWire) {
    const Payload payload{7, 0, {template_definition(ModuleType::rgbdm, 5)}};
    const Bytes expected{
        0x08, 0x07,  // 1 timestamp: 7
        0x12, 0x29,  // 2 metrics: 41 bytes
        0x0A, 0x0D, '_',  't', 'y', 'p', 'e', 's', '_', '/', 'r', 'g', 'b', 'd', 'm',  // 1 name
        0x18, 0x05,                                 //   3 timestamp: 5
        0x20, 0x13,                                 //   4 datatype: 19 Template
        0x92, 0x01, 0x13,                           //   18 template_value: 19 bytes
        0x0A, 0x01, '1',                            //     1 version: "1"
        0x12, 0x0C,                                 //     2 metrics: 12 bytes
        0x0A, 0x06, 'c',  'o', 'l', 'o', 'u', 'r',  //       1 name: "colour"
        0x20, 0x05,                                 //       4 datatype: 5 UInt8
        0x38, 0x01,                                 //       7 is_null: no value
        0x28, 0x01,                                 //     5 is_definition: true
        0x18, 0x00,                                 // 3 seq: 0
    };
    EXPECT_EQ(encode(payload), expected);
    EXPECT_EQ(decode(expected).value(), payload);
}

TEST(SparkplugTemplate, AnInstanceInDataByAliasWithoutDatatypes) {
    auto instance = template_instance(
        ModuleType::rgbdm, {Metric{"colour", std::nullopt, 5, 5, Value(std::uint64_t{3})}}, 9, 5);
    instance.name.clear();
    const Payload payload{7, 1, {instance}};
    const Bytes expected{
        0x08, 0x07,                                 // 1 timestamp: 7
        0x12, 0x1E,                                 // 2 metrics: 30 bytes
        0x10, 0x09,                                 //   2 alias: 9
        0x18, 0x05,                                 //   3 timestamp: 5 (no datatype: DATA)
        0x92, 0x01, 0x17,                           //   18 template_value: 23 bytes
        0x12, 0x0C,                                 //     2 metrics: 12 bytes
        0x0A, 0x06, 'c',  'o', 'l', 'o', 'u', 'r',  //       1 name: "colour"
        0x18, 0x05,                                 //       3 timestamp: 5
        0x50, 0x03,                                 //       10 int_value: 3 (no datatype)
        0x22, 0x05, 'r',  'g', 'b', 'd', 'm',       //     4 template_ref: "rgbdm"
        0x28, 0x00,                                 //     5 is_definition: false, yet there
        0x18, 0x01,                                 // 3 seq: 1
    };
    EXPECT_EQ(encode(payload, Datatypes::left_out), expected);
}

TEST(SparkplugTemplate, DefinitionsAndInstancesDecodeAsTheyWereSent) {
    for (const auto type : {std::optional(ModuleType::dim16), std::optional(ModuleType::acm3p),
                            std::optional<ModuleType>()}) {
        const auto definition = template_definition(type, 1);
        EXPECT_EQ(definition.name, type ? "_types_/" + std::string(name(*type)) : "_types_/id2");
        EXPECT_EQ(definition.datatype, template_datatype);
        EXPECT_FALSE(definition.value);
        ASSERT_TRUE(definition.template_value);
        const auto& t = *definition.template_value;
        EXPECT_TRUE(t.is_definition);
        EXPECT_EQ(t.version, "1");
        EXPECT_EQ(t.template_ref, "");
        const auto specs = module_metrics(type);
        ASSERT_EQ(t.members.size(), specs.size());
        for (std::size_t i = 0; i < specs.size(); ++i) {
            EXPECT_EQ(t.members[i].name, specs[i].name);
            EXPECT_EQ(t.members[i].datatype, static_cast<std::uint32_t>(specs[i].type));
            EXPECT_FALSE(t.members[i].value);  // names and datatypes, no values
        }
        auto member = Metric{specs[0].name, std::nullopt, 1,
                             static_cast<std::uint32_t>(specs[0].type), std::nullopt};
        member.properties = {{"documentation", std::string("boiler 1")}};
        const auto instance = template_instance(type, {member}, 40, 1);
        EXPECT_EQ(instance.name, template_name(type));
        EXPECT_EQ(instance.alias, 40u);
        EXPECT_EQ(instance.template_value->template_ref, template_name(type));
        EXPECT_FALSE(instance.template_value->is_definition);
        const Payload payload{1, 0, {definition, instance}};
        EXPECT_EQ(decode(encode(payload)).value(), payload);
    }
}

TEST(SparkplugTemplate, NestingBeyondTheBoundIsMalformed) {
    Metric metric{"deep", std::nullopt, std::nullopt, template_datatype, std::nullopt};
    metric.template_value = Template{};
    for (int depth = 0; depth < max_template_depth; ++depth) {
        Metric outer{"deep", std::nullopt, std::nullopt, template_datatype, std::nullopt};
        outer.template_value = Template{{}, {}, false, {metric}};
        metric = outer;
    }
    const auto decoded = decode(encode(Payload{1, 0, {metric}}));
    ASSERT_FALSE(decoded);
    EXPECT_EQ(decoded.error().code, Errc::malformed);
    EXPECT_TRUE(decode(encode(Payload{1, 0, {metric.template_value->members[0]}})));
}

TEST(SparkplugTemplate, RecordsAreFlatAndAnInstanceFlattens) {
    auto instance =
        template_instance(ModuleType::dim16,
                          {Metric{"in/0", std::nullopt, 3, 11, Value(true)},
                           Metric{"word", std::nullopt, std::nullopt, 6, Value(std::uint64_t{1})}},
                          std::nullopt, 4);
    instance.is_historical = true;
    const Metric flat{"in/1", std::nullopt, 2, 11, Value(false)};
    const auto out = to_flat({flat, instance});
    ASSERT_EQ(out.size(), 3u);
    EXPECT_EQ(out[0], flat);
    EXPECT_EQ(out[1].name, "in/0");
    EXPECT_EQ(out[1].timestamp, 3u);
    EXPECT_TRUE(out[1].is_historical);
    EXPECT_EQ(out[2].name, "word");
    EXPECT_EQ(out[2].timestamp, 4u);  // the instance's, when the member has none
}

// A DCMD instance names its members: they are what counts against the device's writable metrics.
Payload instance_command(std::size_t members, std::string_view type = "dom16") {
    Metric metric{std::string(type), std::nullopt, 17, template_datatype, std::nullopt};
    metric.template_value = Template{{}, std::string(type), false, {}};
    for (std::size_t i = 0; i < members; ++i)
        metric.template_value->members.push_back(
            Metric{fmt::format("out/{}", i % 16), std::nullopt, 17, 11, Value(true)});
    return Payload{17, std::nullopt, {metric}};
}

TEST(SparkplugTemplate, AnInstanceCommandCountsItsMembers) {
    const auto dom16 = writable_metrics(ModuleType::dom16);
    for (const std::size_t n : {0u, 1u, 17u, 18u, 1000u}) {
        const auto bytes = encode(instance_command(n));
        EXPECT_EQ(count_command_metrics(bytes).value(), std::max<std::size_t>(n, 1)) << n;
        EXPECT_EQ(count_metrics(bytes).value(), 1u);
    }
    // a payload without templates counts as count_metrics counts it
    const auto flat = encode(command_of(17));
    EXPECT_EQ(count_command_metrics(flat).value(), 17u);
    const auto fits = decode_command(encode(instance_command(dom16)), dom16);
    ASSERT_TRUE(fits) << fits.error().message;
    EXPECT_EQ(command_metrics(fits->metrics), dom16);
    const auto over = decode_command(encode(instance_command(dom16 + 1)), dom16);
    ASSERT_FALSE(over);
    EXPECT_EQ(over.error().code, Errc::invalid_argument);
    EXPECT_NE(over.error().message.find("names 18 metrics, and the device has 17 writable"),
              std::string::npos)
        << over.error().message;
    // two instances of 9 members: 18 as well
    auto two = instance_command(9);
    two.metrics.push_back(two.metrics[0]);
    EXPECT_FALSE(decode_command(encode(two), dom16));
    // a template field that is not a message is malformed, as any bad field is
    const Bytes bad{0x12, 0x05, 0x92, 0x01, 0x02, 0x12, 0x40};
    EXPECT_EQ(count_command_metrics(bad).error().code, Errc::malformed);
}

TEST(SparkplugTemplate, AnInstanceCommandIsAWriteOfItsMembers) {
    const auto command = instance_command(2).metrics[0];
    const auto writes = command_writes(ModuleType::dom16, command, true);
    ASSERT_TRUE(writes) << writes.error().message;
    EXPECT_EQ(*writes, command.template_value->members);
    for (const auto& write : *writes)
        EXPECT_TRUE(plan_command(ModuleAddress{ModuleType::dom16, 0}, write.name, write.datatype,
                                 write.value));
    // a flat metric is itself, with templates or without
    const Metric flat{"out/3", std::nullopt, 1, 11, Value(true)};
    EXPECT_EQ(command_writes(ModuleType::dom16, flat, true).value(), std::vector<Metric>{flat});
    EXPECT_EQ(command_writes(ModuleType::dom16, flat, false).value(), std::vector<Metric>{flat});
    const auto refused_for = [&](Metric metric, bool templates = true) {
        const auto result = command_writes(ModuleType::dom16, metric, templates);
        EXPECT_FALSE(result);
        if (result) return std::string();
        EXPECT_EQ(result.error().code, Errc::invalid_argument);
        return result.error().message;
    };
    EXPECT_NE(refused_for(command, false).find("publishes none"), std::string::npos);
    auto definition = command;
    definition.template_value->is_definition = true;
    EXPECT_NE(refused_for(definition).find("definition is not a command"), std::string::npos);
    EXPECT_NE(refused_for(instance_command(1, "rgbdm").metrics[0]).find("not this device's"),
              std::string::npos);
    auto other_ref = command;
    other_ref.template_value->template_ref = "rgbdm";
    EXPECT_NE(refused_for(other_ref).find("template_ref rgbdm is not dom16"), std::string::npos);
    auto by_alias = command;
    by_alias.template_value->members[0].name.clear();
    by_alias.template_value->members[0].alias = 3;
    EXPECT_NE(refused_for(by_alias).find("members go by name"), std::string::npos);
    auto nested = command;
    nested.template_value->members[0] = command;
    nested.template_value->members[0].name = "out/0";
    EXPECT_NE(refused_for(nested).find("member out/0 is a Template"), std::string::npos);
    auto no_value = command;
    no_value.template_value.reset();
    EXPECT_NE(refused_for(no_value).find("without a Template value"), std::string::npos);
}

}  // namespace
}  // namespace ioport::sparkplug
