// Plain MQTT with JSON and Home Assistant discovery (gateway.md §6.3) as pure functions.
#include "protocol/mqtt_json.hpp"

#include "daemon/mqtt_json/birth_pacer.hpp"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>

namespace ioport::mqtt_json {
namespace {

const ModuleAddress dim16{ModuleType::dim16, 0};
const ModuleAddress dom16{ModuleType::dom16, 1};
const ModuleAddress acm3p{ModuleType::acm3p, 0};
const ModuleAddress rgbdm{ModuleType::rgbdm, 2};
const ModuleAddress mux8m{ModuleType::mux8m, 0};

TEST(MqttJsonTopics, AsGatewayMdSays) {
    EXPECT_EQ(status_topic("ioportd/box7"), "ioportd/box7/status");
    EXPECT_EQ(module_topic("ioportd/box7", "hub0", dom16, "state"),
              "ioportd/box7/hub0/dom16_1/state");
    EXPECT_EQ(module_topic("ioportd/box7", "press", std::nullopt, "availability"),
              "ioportd/box7/press/id2/availability");
    EXPECT_EQ(set_subscription("ioportd/box7"), "ioportd/box7/+/+/+/set");
    EXPECT_EQ(parse_set_topic("ioportd/box7", "ioportd/box7/hub0/dom16_1/out3/set"),
              (SetTopic{"hub0", "dom16_1", "out3"}));
    for (const char* topic :
         {"ioportd/box7/hub0/dom16_1/out3", "ioportd/box7/hub0/dom16_1/out3/set/x",
          "ioportd/box7/hub0//out3/set", "ioportd/box7x/hub0/dom16_1/out3/set",
          "ioportd/box7/hub0/dom16_1/out3/get", "ioportd/box7", "ioportd/box7/", ""})
        EXPECT_EQ(parse_set_topic("ioportd/box7", topic), std::nullopt) << topic;
}

TEST(MqttJsonTopics, APrefixIsLevelsOfPrintableUtf8WithoutWildcards) {
    for (const char* good : {"ioportd", "ioportd/box7", "plant 1/hall-2/box_7", "Ü/°C"})
        EXPECT_TRUE(check_topic_prefix(good)) << good;
    const auto why = [](std::string_view prefix) {
        const auto checked = check_topic_prefix(prefix);
        return checked ? std::string("accepted") : checked.error().message;
    };
    EXPECT_EQ(why(""), "must not be empty");
    EXPECT_EQ(why("a/+"), "has '+', an MQTT wildcard, at byte 2");
    EXPECT_EQ(why("#"), "has '#', an MQTT wildcard, at byte 0");
    EXPECT_EQ(why("$SYS"), "starts with '$', which brokers keep for their own topics");
    for (const char* empty_level : {"/a", "a/", "a//b", "/"})
        EXPECT_NE(why(empty_level).find("empty topic level"), std::string::npos) << empty_level;
    EXPECT_EQ(why(std::string_view("a\0b", 3)), "has a control character at byte 1");
    EXPECT_EQ(why("a\x7F"), "has a control character at byte 1");
    EXPECT_EQ(why("ab\xC3"), "is not valid UTF-8 at byte 2");
    EXPECT_EQ(why("a\xFF"), "is not valid UTF-8 at byte 1");
    EXPECT_EQ(why(std::string(max_topic_prefix, 'p')), "accepted");
    EXPECT_EQ(why(std::string(max_topic_prefix + 1, 'p')), "is 129 bytes long: at most 128");
}

// The state document of what the core holds of a module.
std::string state_of(std::optional<ModuleType> type, const gateway::ModuleReadings& now,
                     const gateway::ModuleTags& tags = gateway::no_tags) {
    std::vector<std::optional<gateway::PointValue>> values;
    gateway::point_values(type, now, tags, values);
    return state_json(type, values);
}

TEST(MqttJsonState, EveryKeyOfTheModuleNullUntilRead) {
    EXPECT_EQ(state_of(ModuleType::dim16, {}),
              R"({"in0":null,"in1":null,"in2":null,"in3":null,"in4":null,"in5":null,"in6":null,)"
              R"("in7":null,"in8":null,"in9":null,"in10":null,"in11":null,"in12":null,)"
              R"("in13":null,"in14":null,"in15":null,"word":null})");
    const auto dim = state_of(ModuleType::dim16, {Reading{{0x8001, 0, 0}, 1}, {}, {}, {}});
    EXPECT_NE(dim.find(R"("in0":true,"in1":false)"), std::string::npos) << dim;
    EXPECT_NE(dim.find(R"("in15":true,"word":32769})"), std::string::npos) << dim;
    EXPECT_EQ(state_of(ModuleType::rgbdm, {{}, 3, {}, {}}), R"({"colour":"blue"})");
    EXPECT_EQ(state_of(ModuleType::mux8m, {{}, 0x0302, {}, {}}), R"({"pos":3,"neg":2})");
    EXPECT_EQ(state_of(std::nullopt, {{}, {}, true, 42}), R"({"stop":true,"count":42})");
}

TEST(MqttJsonState, AnalogValuesAreTheEngineeringValues) {
    auto tags = gateway::default_tags(acm3p);
    tags.channels[0].scale = gateway::Scale{0, 100, -20, 150};
    const auto text =
        state_of(ModuleType::acm3p, {Reading{{0, 32768, 65535}, 3}, {}, {}, {}}, tags);
    EXPECT_EQ(text, R"({"raw0":0,"raw1":32768,"raw2":65535,"value0":-20,"value1":50.000763,)"
                    R"("value2":100})");
    EXPECT_EQ(state_keys(ModuleType::dccim), (std::vector<std::string>{"raw0", "value0"}));
}

// --- Home Assistant discovery -------------------------------------------------------------

const Node node{"homeassistant", "ioportd/box7", "0.1.0"};

const Discovery* find(const std::vector<Discovery>& configs, std::string_view topic) {
    const auto found = std::ranges::find(configs, topic, &Discovery::topic);
    return found == configs.end() ? nullptr : &*found;
}

TEST(MqttJsonDiscovery, NodeIdsAndDeviceClasses) {
    EXPECT_EQ(node_id("ioportd/box7"), "ioportd_box7");
    EXPECT_EQ(node_id("plant 1/ä"), "plant_1___");
    EXPECT_EQ(device_class("°C"), "temperature");
    EXPECT_EQ(device_class("bar"), "pressure");
    EXPECT_EQ(device_class("mA"), "current");
    EXPECT_EQ(device_class("V"), "voltage");
    EXPECT_EQ(device_class("%"), "");  // a plain percentage has no class
    EXPECT_EQ(device_class("C"), "");  // Home Assistant would refuse the config
    EXPECT_EQ(device_class("degC"), "");
}

TEST(MqttJsonDiscovery, TheGatewaysOwnDevice) {
    const auto gateway = gateway_discovery(node);
    EXPECT_EQ(gateway.topic, "homeassistant/binary_sensor/ioportd_box7/connection/config");
    EXPECT_EQ(gateway.payload,
              R"({"name":"connection","unique_id":"ioportd_box7_connection",)"
              R"("state_topic":"ioportd/box7/status","payload_on":"online",)"
              R"("payload_off":"offline","device_class":"connectivity",)"
              R"("entity_category":"diagnostic","device":{"identifiers":["ioportd_box7"],)"
              R"("name":"ioportd ioportd/box7","manufacturer":"ioportd",)"
              R"("model":"serial-to-Modbus gateway","sw_version":"0.1.0"},)"
              R"("origin":{"name":"ioportd","sw_version":"0.1.0"}})");
}

TEST(MqttJsonDiscovery, AnAnalogChannelIsASensorInItsUnit) {
    auto tags = gateway::default_tags(acm3p);
    tags.name = "boiler 1";
    tags.channels[0] = {"supply temperature", "°C", gateway::Scale{0, 100, -20, 150}, {-20, 150}};
    const auto configs = module_discovery(node, "hub0", acm3p, tags);
    ASSERT_EQ(configs.size(), 3U);
    const auto* value0 =
        find(configs, "homeassistant/sensor/ioportd_box7/hub0_acm3p_0_value0/config");
    ASSERT_NE(value0, nullptr);
    EXPECT_EQ(value0->payload,
              R"({"name":"supply temperature","unique_id":"ioportd_box7_hub0_acm3p_0_value0",)"
              R"("availability":[{"topic":"ioportd/box7/status"},)"
              R"({"topic":"ioportd/box7/hub0/acm3p_0/availability"}],"availability_mode":"all",)"
              R"("origin":{"name":"ioportd","sw_version":"0.1.0"},)"
              R"("state_topic":"ioportd/box7/hub0/acm3p_0/state",)"
              R"("value_template":"{{ value_json.value0 }}","state_class":"measurement",)"
              R"("suggested_display_precision":1,"unit_of_measurement":"°C",)"
              R"("device_class":"temperature","device":{"identifiers":)"
              R"(["ioportd_box7_hub0_acm3p_0"],"name":"boiler 1","manufacturer":"iomlogic",)"
              R"("model":"acm3p","via_device":"ioportd_box7"}})");
    const auto* value1 =
        find(configs, "homeassistant/sensor/ioportd_box7/hub0_acm3p_0_value1/config");
    ASSERT_NE(value1, nullptr);
    EXPECT_NE(value1->payload.find(R"("name":"channel 1")"), std::string::npos);
    EXPECT_NE(value1->payload.find(R"("unit_of_measurement":"%")"), std::string::npos);
    EXPECT_EQ(value1->payload.find("device_class"), std::string::npos);
}

TEST(MqttJsonDiscovery, EveryModuleTypeHasItsComponents) {
    const auto count = [](const std::vector<Discovery>& configs, std::string_view component) {
        return std::ranges::count_if(configs, [&](const Discovery& d) {
            return d.topic.starts_with("homeassistant/" + std::string(component) + "/");
        });
    };
    auto inputs = gateway::default_tags(dim16);
    inputs.points[5] = "pump running";
    const auto dim = module_discovery(node, "hub0", dim16, inputs);
    EXPECT_EQ(count(dim, "binary_sensor"), 16);
    const auto* in5 = find(dim, "homeassistant/binary_sensor/ioportd_box7/hub0_dim16_0_in5/config");
    ASSERT_NE(in5, nullptr);
    EXPECT_NE(in5->payload.find(R"("name":"pump running")"), std::string::npos);
    EXPECT_NE(in5->payload.find(R"("value_template":"{{ 'ON' if value_json.in5 else 'OFF' }}")"),
              std::string::npos);

    const auto dom = module_discovery(node, "hub0", dom16, gateway::default_tags(dom16));
    EXPECT_EQ(count(dom, "switch"), 16);
    const auto* out0 = find(dom, "homeassistant/switch/ioportd_box7/hub0_dom16_1_out0/config");
    ASSERT_NE(out0, nullptr);
    for (const auto* key :
         {R"("command_topic":"ioportd/box7/hub0/dom16_1/out0/set")", R"("payload_on":"ON")",
          R"("payload_off":"OFF")", R"("optimistic":false)", R"("name":"output 0")"})
        EXPECT_NE(out0->payload.find(key), std::string::npos) << key << "\n" << out0->payload;

    const auto rgb = module_discovery(node, "hub0", rgbdm, gateway::default_tags(rgbdm));
    ASSERT_EQ(count(rgb, "select"), 1);
    EXPECT_NE(rgb[0].payload.find(
                  R"("options":["off","red","green","blue","cyan","magenta","yellow","white"])"),
              std::string::npos)
        << rgb[0].payload;

    const auto mux = module_discovery(node, "hub0", mux8m, gateway::default_tags(mux8m));
    ASSERT_EQ(count(mux, "number"), 2);
    EXPECT_NE(mux[0].payload.find(R"("min":0,"max":7,"step":1,"mode":"box")"), std::string::npos);
    EXPECT_NE(mux[0].payload.find(R"("command_template":"{{ value | int }}")"), std::string::npos);

    const auto id2 = module_discovery(node, "press", std::nullopt, gateway::no_tags);
    ASSERT_EQ(id2.size(), 3U);
    EXPECT_EQ(id2[0].topic, "homeassistant/binary_sensor/ioportd_box7/press_id2_stop/config");
    EXPECT_NE(id2[0].payload.find(R"("device_class":"problem")"), std::string::npos);
    EXPECT_NE(id2[1].payload.find(R"("state_class":"total_increasing")"), std::string::npos);
    EXPECT_EQ(id2[2].topic, "homeassistant/button/ioportd_box7/press_id2_reset/config");
    EXPECT_NE(id2[2].payload.find(R"("payload_press":"ON")"), std::string::npos);
    EXPECT_NE(id2[2].payload.find(R"("name":"ID-2 press")"), std::string::npos);
    // Every unique id is unique.
    std::vector<std::string> ids;
    for (const auto* configs : {&dim, &dom, &rgb, &mux, &id2})
        for (const auto& d : *configs)
            ids.push_back(d.topic);
    std::ranges::sort(ids);
    EXPECT_EQ(std::ranges::adjacent_find(ids), ids.end());
}

// --- The bridge topics (gateway.md §7.3) ------------------------------------------------------

TEST(MqttJsonBridge, TopicsAndRequestNames) {
    EXPECT_EQ(bridge_topic("ioportd/box7", "info"), "ioportd/box7/bridge/info");
    EXPECT_EQ(bridge_request_subscription("p"), "p/bridge/request/+");
    EXPECT_EQ(parse_bridge_request("p", "p/bridge/request/health_check"), "health_check");
    for (const auto topic :
         {"p/bridge/request/", "p/bridge/request/a/b", "p/bridge/response/x", "p/bridge/info",
          "q/bridge/request/x", "p/hub0/dom16_0/out3/set", "pp/bridge/request/x"})
        EXPECT_FALSE(parse_bridge_request("p", topic)) << topic;
    // A link named "bridge" keeps its module topics apart: their third level is a module id.
    EXPECT_EQ(parse_set_topic("p", "p/bridge/request/x"), std::nullopt);
}

TEST(MqttJsonBridge, InfoDescribesTheLinksAndModules) {
    const std::vector<BridgeLink> links{
        {"hub0", "ioport", 1, {{"dim16_0", "dim16", "inputs", "online"}}},
        {"press", "id2", 2, {{"id2", "id2", "ID-2", "no answer"}}}};
    EXPECT_EQ(bridge_info_json("0.1.0", links, true, false),
              R"({"version":"0.1.0","links":[{"name":"hub0","protocol":"ioport","unit_id":1,)"
              R"("modules":[{"id":"dim16_0","type":"dim16","name":"inputs","status":"online"}]},)"
              R"({"name":"press","protocol":"id2","unit_id":2,"modules":[{"id":"id2",)"
              R"("type":"id2","name":"ID-2","status":"no answer"}]}],"discovery":true,)"
              R"("read_only":false})");
}

TEST(MqttJsonBridge, ARequestIsAJsonObjectWhoseTransactionIsEchoedAsItCame) {
    EXPECT_EQ(parse_bridge_request_payload("{}").transaction, std::nullopt);
    EXPECT_EQ(parse_bridge_request_payload("{}").error, "");
    EXPECT_EQ(parse_bridge_request_payload(R"({"transaction": "a\"b"})").transaction, R"("a\"b")");
    EXPECT_EQ(parse_bridge_request_payload(R"({"transaction":12, "x": [1]})").transaction, "12");
    EXPECT_EQ(parse_bridge_request_payload(R"({"transaction": 1.5})").transaction, "1.5");
    EXPECT_EQ(parse_bridge_request_payload(R"({"transaction": true})").transaction, "true");
    for (const auto payload : {"", "x", "[1]", "1", R"({"transaction": 1)",
                               R"({"transaction": 1e400})", R"({"x": -1e999, "transaction": 1})"}) {
        const auto request = parse_bridge_request_payload(payload);
        EXPECT_TRUE(request.error.starts_with("the payload is "))
            << payload << ": " << request.error;
        EXPECT_EQ(request.transaction, std::nullopt);
    }
    const std::vector<std::string> refused{"null", "[1]", "{}",
                                           "\"" + std::string(129, 'x') + "\""};
    for (const auto& transaction : refused) {
        const auto request =
            parse_bridge_request_payload(fmt::format(R"({{"transaction": {}}})", transaction));
        EXPECT_EQ(request.error,
                  "transaction: a string of at most 128 bytes, a number or a boolean")
            << transaction;
    }
    EXPECT_EQ(parse_bridge_request_payload(
                  fmt::format(R"({{"transaction": "{}"}})", std::string(128, 'x')))
                  .error,
              "");
    // The parser quotes what it read last: of a 60 KB string or number, a bounded part goes in
    // the answer, cut where a UTF-8 sequence ends.
    for (const auto& payload :
         {R"({"transaction": ")" + std::string(60000, 'x'),
          R"({"transaction": 1)" + std::string(60000, '0') + "}",
          R"({"transaction": ")" + std::string(100, 'x') + std::string(20000, '\xC3') + "\xA9"}) {
        const auto error = parse_bridge_request_payload(payload).error;
        EXPECT_TRUE(error.starts_with("the payload is not JSON: ")) << error;
        EXPECT_LE(error.size(), 300U) << error;
        EXPECT_NE(error.find("...: send a JSON object"), std::string::npos) << error;
    }
}

TEST(MqttJsonBridge, ResponsesAndTheHealthCheck) {
    EXPECT_EQ(bridge_response_json(R"({"a":1})", "", std::nullopt),
              R"({"status":"ok","data":{"a":1}})");
    EXPECT_EQ(bridge_response_json(R"({"a":1})", "no such request", std::string("\"t\"")),
              R"({"status":"error","data":{},"error":"no such request","transaction":"t"})");
    const std::vector<std::pair<std::string, std::string>> fine{{"hub0", "ok"}, {"press", "ok"}};
    EXPECT_EQ(health_json(fine), R"({"healthy":true,"links":{"hub0":"ok","press":"ok"}})");
    const std::vector<std::pair<std::string, std::string>> not_fine{
        {"hub0", "ok"}, {"press", "link press: port /dev/ttyS0 not open"}};
    EXPECT_EQ(health_json(not_fine), R"({"healthy":false,"links":{"hub0":"ok",)"
                                     R"("press":"link press: port /dev/ttyS0 not open"}})");
}

TEST(MqttJsonBridge, ALinksConnectivityIsASensorOfTheGatewaysDevice) {
    const auto config = link_discovery(node, "hub.0");  // the file's node, ioportd/box7
    EXPECT_EQ(config.topic, "homeassistant/binary_sensor/ioportd_box7/hub_0_connectivity/config");
    EXPECT_EQ(config.payload,
              R"({"name":"link hub.0","unique_id":"ioportd_box7_hub_0_connectivity",)"
              R"("state_topic":"ioportd/box7/bridge/connectivity/hub.0",)"
              R"("availability_topic":"ioportd/box7/status","device_class":"connectivity",)"
              R"("entity_category":"diagnostic","device":{"identifiers":["ioportd_box7"]},)"
              R"("origin":{"name":"ioportd","sw_version":"0.1.0"}})");
}

}  // namespace
}  // namespace ioport::mqtt_json

// Home Assistant's birth (gateway.md §7.5), on a clock of the test's: no waiting.
namespace ioport::daemon {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

TEST(BirthPacer, AtOnceThenAtMostOnceAnIntervalTheLastHeldBackServedWhenItEnds) {
    BirthPacer pacer(seconds(30));
    const BirthPacer::Clock::time_point t0{std::chrono::hours(1)};
    EXPECT_FALSE(pacer.due_at());
    EXPECT_FALSE(pacer.due(t0));
    EXPECT_TRUE(pacer.asked(t0));  // the first: at once
    EXPECT_FALSE(pacer.due_at());
    // A burst (295 births in 6 s once made 710 messages): none served, one due at t0 + 30 s.
    for (int i = 1; i <= 295; ++i)
        EXPECT_FALSE(pacer.asked(t0 + milliseconds(20 * i)));
    EXPECT_EQ(pacer.due_at(), t0 + seconds(30));
    EXPECT_FALSE(pacer.due(t0 + seconds(29)));
    EXPECT_TRUE(pacer.due(t0 + seconds(30)));  // once, when the 30 s end
    EXPECT_FALSE(pacer.due(t0 + seconds(31)));
    EXPECT_FALSE(pacer.due_at());
    // That republication counts: a birth right after it waits a whole interval again.
    EXPECT_FALSE(pacer.asked(t0 + seconds(31)));
    EXPECT_EQ(pacer.due_at(), t0 + seconds(60));
    EXPECT_TRUE(pacer.due(t0 + seconds(61)));
    // Quiet for longer than the interval: the next birth is served at once, nothing held back.
    EXPECT_TRUE(pacer.asked(t0 + seconds(100)));
    EXPECT_FALSE(pacer.due(t0 + seconds(200)));
}

TEST(BirthPacer, ABirthServedAtOnceCancelsNothingDue) {
    BirthPacer pacer(seconds(30));
    const BirthPacer::Clock::time_point t0{std::chrono::hours(1)};
    EXPECT_TRUE(pacer.asked(t0));
    EXPECT_FALSE(pacer.asked(t0 + seconds(10)));
    // The timer that serves it was late (a busy loop): a birth after the interval is served
    // at once and the held-back one with it, not a second time.
    EXPECT_TRUE(pacer.asked(t0 + seconds(45)));
    EXPECT_FALSE(pacer.due_at());
    EXPECT_FALSE(pacer.due(t0 + seconds(50)));
}

}  // namespace
}  // namespace ioport::daemon
