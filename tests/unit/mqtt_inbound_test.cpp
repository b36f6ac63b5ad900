#include "protocol/mqtt_inbound.hpp"

#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace ioport::mqtt {
namespace {

using Bytes = std::vector<std::uint8_t>;

Bytes bytes(std::initializer_list<int> values) {
    Bytes out;
    for (const int v : values)
        out.push_back(static_cast<std::uint8_t>(v));
    return out;
}

// A PUBLISH of `qos` on `topic` with `payload_bytes` bytes of 'x' (MQTT 3.1.1 §3.3).
Bytes publish(std::string_view topic, std::size_t payload_bytes, int qos, std::uint16_t id = 0) {
    Bytes body{0, static_cast<std::uint8_t>(topic.size())};
    body.insert(body.end(), topic.begin(), topic.end());
    if (qos > 0)
        body.insert(body.end(),
                    {static_cast<std::uint8_t>(id >> 8), static_cast<std::uint8_t>(id & 0xff)});
    body.insert(body.end(), payload_bytes, 'x');
    Bytes packet{static_cast<std::uint8_t>(0x30 | (qos << 1))};
    for (std::size_t length = body.size();;) {  // §2.2.3: 7 bits a byte, least significant first
        const auto byte = static_cast<std::uint8_t>(length & 0x7f);
        length >>= 7;
        packet.push_back(length > 0 ? (byte | 0x80) : byte);
        if (length == 0) break;
    }
    packet.insert(packet.end(), body.begin(), body.end());
    return packet;
}

struct Taken {
    Bytes out;
    std::vector<RefusedPublish> refused;
    Result<> result;
};

// Fed `chunk` bytes at a time, as reads from a socket may cut the stream anywhere.
Taken take(InboundLimit& limit, const Bytes& in, std::size_t chunk = SIZE_MAX) {
    Taken taken;
    for (std::size_t at = 0; at < in.size() && taken.result; at += chunk) {
        const auto n = std::min(chunk, in.size() - at);
        taken.result = limit.take(std::span(in).subspan(at, n), taken.out, taken.refused);
    }
    return taken;
}

TEST(MqttInboundLimit, PacketsWithinTheLimitPassByteForByteHoweverTheStreamIsCut) {
    Bytes stream = bytes({0x20, 0x02, 0x00, 0x00});  // CONNACK, accepted
    auto message = publish("a/b", 100, 1, 7);        // 108 bytes in all
    stream.insert(stream.end(), message.begin(), message.end());
    stream.insert(stream.end(), {0xd0, 0x00});  // PINGRESP: no remaining length
    for (const std::size_t chunk : {std::size_t{1}, std::size_t{3}, SIZE_MAX}) {
        InboundLimit limit(message.size());
        const auto taken = take(limit, stream, chunk);
        ASSERT_TRUE(taken.result) << taken.result.error().message;
        EXPECT_EQ(taken.out, stream) << "chunks of " << chunk;
        EXPECT_TRUE(taken.refused.empty());
    }
}

TEST(MqttInboundLimit, AQos0PublishOneByteBeyondTheLimitIsRefusedAndNotPassed) {
    const auto huge = publish("spBv1.0/g/DCMD/n/d", 200, 0);
    const auto after = publish("x", 1, 0);
    Bytes stream = huge;
    stream.insert(stream.end(), after.begin(), after.end());
    for (const std::size_t chunk : {std::size_t{1}, std::size_t{7}, SIZE_MAX}) {
        InboundLimit limit(huge.size() - 1);
        const auto taken = take(limit, stream, chunk);
        ASSERT_TRUE(taken.result) << taken.result.error().message;
        EXPECT_EQ(taken.out, after) << "only the packet after it, whole";
        ASSERT_EQ(taken.refused.size(), 1U);
        EXPECT_EQ(taken.refused[0].topic, "spBv1.0/g/DCMD/n/d");
        EXPECT_EQ(taken.refused[0].packet_bytes, huge.size());
        EXPECT_EQ(taken.refused[0].qos, 0);
    }
}

TEST(MqttInboundLimit, AQos1PublishBeyondTheLimitBecomesAnEmptyOneWithItsPacketId) {
    InboundLimit limit(1024);
    auto huge = publish("t", 70000, 1, 0x1234);
    huge[0] |= 0x09;  // DUP and RETAIN kept as they were
    const auto taken = take(limit, huge, 4096);
    ASSERT_TRUE(taken.result) << taken.result.error().message;
    Bytes expected = bytes({0x3b, 20, 0, 16});  // PUBLISH QoS 1 DUP RETAIN, 20 bytes; topic of 16
    const std::string_view topic = refused_publish_topic;
    expected.insert(expected.end(), topic.begin(), topic.end());
    expected.insert(expected.end(), {0x12, 0x34});  // the packet identifier, no payload
    EXPECT_EQ(taken.out, expected);
    ASSERT_EQ(taken.refused.size(), 1U);
    EXPECT_EQ(taken.refused[0].qos, 1);
    EXPECT_EQ(taken.refused[0].packet_bytes, huge.size());
}

TEST(MqttInboundLimit, A256MiBRemainingLengthIsNeverHeld) {
    // The largest length MQTT can say (0xff 0xff 0xff 0x7f): refused on its header, read in
    // passing; what the bound holds meanwhile is the topic alone.
    InboundLimit limit(65536);
    Bytes head = bytes({0x30, 0xff, 0xff, 0xff, 0x7f, 0x00, 0x01, 'a'});
    std::vector<RefusedPublish> refused;
    Bytes out;
    ASSERT_TRUE(limit.take(head, out, refused));
    ASSERT_EQ(refused.size(), 1U);
    EXPECT_EQ(refused[0].packet_bytes, 5U + 268'435'455U);
    const Bytes block(1 << 20, 'x');
    for (int i = 0; i < 255; ++i)
        ASSERT_TRUE(limit.take(block, out, refused));
    EXPECT_TRUE(out.empty());
    const auto next = bytes({0xd0, 0x00});
    ASSERT_TRUE(limit.take(Bytes((1 << 20) - 4, 'x'), out, refused));  // 3 came with the topic
    ASSERT_TRUE(limit.take(next, out, refused));
    EXPECT_EQ(out, next) << "the packet after the refused one starts where it ends";
}

TEST(MqttInboundLimit, WhatIsNotMqttFailsTheStream) {
    struct Case {
        const char* what;
        Bytes stream;
    };
    const Case cases[] = {
        {"five length bytes", bytes({0x30, 0x80, 0x80, 0x80, 0x80, 0x01})},
        {"an oversized SUBACK", bytes({0x90, 0xff, 0x7f})},
        {"an oversized PUBLISH of QoS 3", bytes({0x36, 0xff, 0x7f})},
        {"a topic longer than its packet", bytes({0x30, 0x82, 0x01, 0xff, 0xff})},
        {"an oversized PUBLISH of one byte", bytes({0x30, 0x01})},
    };
    for (const auto& c : cases) {
        InboundLimit limit(0);
        const auto taken = take(limit, c.stream);
        EXPECT_FALSE(taken.result) << c.what;
    }
}

}  // namespace
}  // namespace ioport::mqtt
