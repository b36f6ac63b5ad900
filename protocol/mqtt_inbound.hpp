// A bound on what an MQTT 3.1.1 broker can make its client hold. MQTT 3.1.1 has no way to ask
// a broker for smaller packets (MQTT 5's Maximum Packet Size), and libmosquitto allocates a
// packet's whole remaining length before it reads it. So the broker's byte stream passes through
// this first: every packet within `limit` bytes goes on as it is, byte for byte; a PUBLISH
// beyond it is read in passing, never held, and only its topic is kept. Where it was QoS 1 or 2
// an empty PUBLISH with the same packet identifier and flags takes its place, on
// `refused_publish_topic`, so that the client still acknowledges what the broker sent.
//
// Pure: bytes in, bytes out. The relay that feeds it lives in daemon/mqtt/broker_relay.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "protocol/error.hpp"

namespace ioport::mqtt {

// The topic of the placeholder for a refused QoS 1 or 2 PUBLISH. Brokers do not deliver topics
// beginning with '$' that a client published, so no real message is taken for it.
inline constexpr std::string_view refused_publish_topic = "$ioportd/refused";

struct RefusedPublish {
    std::string topic;           // as the broker sent it; not yet checked as UTF-8
    std::uint64_t packet_bytes;  // fixed header included
    int qos;
};

class InboundLimit {
  public:
    // `limit`: the largest packet passed on, fixed header included (as Maximum Packet Size).
    explicit InboundLimit(std::size_t limit) : limit_(limit) {}

    // Appends to `out` what the client may read of `in`, and to `refused` the PUBLISHes it
    // must not. Fails on a stream that is not MQTT as far as the bound needs to read it: a
    // remaining length of more than 4 bytes, a packet beyond the limit that is not a PUBLISH,
    // a PUBLISH of QoS 3 or whose topic runs past its end. The connection is then to be closed.
    Result<> take(std::span<const std::uint8_t> in, std::vector<std::uint8_t>& out,
                  std::vector<RefusedPublish>& refused);

  private:
    enum class State { header, pass, hold_publish_start, skip };
    Result<> header_done(std::vector<std::uint8_t>& out);
    void publish_start_done(std::vector<std::uint8_t>& out, std::vector<RefusedPublish>& refused);

    std::size_t limit_;
    State state_ = State::header;
    std::vector<std::uint8_t> held_;  // the fixed header, or an oversized PUBLISH's start
    std::uint64_t remaining_ = 0;     // of the packet's remaining length still to come
    std::uint64_t packet_bytes_ = 0;
    std::uint8_t flags_ = 0;  // an oversized PUBLISH's first byte
    std::size_t wanted_ = 0;  // hold_publish_start: bytes of the variable header needed
};

}  // namespace ioport::mqtt
