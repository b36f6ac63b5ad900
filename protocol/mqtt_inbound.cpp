#include "protocol/mqtt_inbound.hpp"

#include <algorithm>

#include <fmt/format.h>

namespace ioport::mqtt {
namespace {

constexpr std::uint8_t publish_type = 3;

int qos_of(std::uint8_t first_byte) {
    return (first_byte >> 1) & 3;
}

}  // namespace

Result<> InboundLimit::take(std::span<const std::uint8_t> in, std::vector<std::uint8_t>& out,
                            std::vector<RefusedPublish>& refused) {
    std::size_t pos = 0;
    while (pos < in.size()) {
        const auto available = in.size() - pos;
        switch (state_) {
            case State::header: {
                const std::uint8_t byte = in[pos++];
                held_.push_back(byte);
                // MQTT 3.1.1 §2.2.3: the remaining length is 1 to 4 bytes, 7 bits each.
                if (held_.size() == 1 || (byte & 0x80) != 0) {
                    if (held_.size() == 5)
                        return fail(Errc::malformed,
                                    "a remaining length of more than 4 bytes (not MQTT)");
                    break;
                }
                if (auto done = header_done(out); !done) return done;
                break;
            }
            case State::pass: {
                const auto n =
                    static_cast<std::size_t>(std::min<std::uint64_t>(remaining_, available));
                out.insert(out.end(), in.begin() + static_cast<std::ptrdiff_t>(pos),
                           in.begin() + static_cast<std::ptrdiff_t>(pos + n));
                pos += n;
                remaining_ -= n;
                if (remaining_ == 0) state_ = State::header;
                break;
            }
            case State::hold_publish_start: {
                const auto n = static_cast<std::size_t>(
                    std::min<std::uint64_t>({wanted_ - held_.size(), remaining_, available}));
                held_.insert(held_.end(), in.begin() + static_cast<std::ptrdiff_t>(pos),
                             in.begin() + static_cast<std::ptrdiff_t>(pos + n));
                pos += n;
                remaining_ -= n;
                if (held_.size() == 2 && wanted_ == 2) {
                    // The topic's length is known: the topic, then the packet identifier.
                    const std::size_t topic_bytes = (std::size_t{held_[0]} << 8) | held_[1];
                    wanted_ = 2 + topic_bytes + (qos_of(flags_) > 0 ? 2 : 0);
                    if (wanted_ - 2 > remaining_)
                        return fail(Errc::malformed,
                                    "a PUBLISH whose topic runs past its end (not MQTT)");
                }
                if (held_.size() == wanted_) publish_start_done(out, refused);
                break;
            }
            case State::skip: {
                const auto n =
                    static_cast<std::size_t>(std::min<std::uint64_t>(remaining_, available));
                pos += n;
                remaining_ -= n;
                if (remaining_ == 0) state_ = State::header;
                break;
            }
        }
    }
    return {};
}

Result<> InboundLimit::header_done(std::vector<std::uint8_t>& out) {
    std::uint64_t length = 0;
    for (std::size_t i = held_.size() - 1; i >= 1; --i)
        length = (length << 7) | (held_[i] & 0x7f);
    remaining_ = length;
    packet_bytes_ = held_.size() + length;
    if (packet_bytes_ <= limit_) {
        out.insert(out.end(), held_.begin(), held_.end());
        held_.clear();
        state_ = remaining_ > 0 ? State::pass : State::header;
        return {};
    }
    flags_ = held_[0];
    held_.clear();
    if ((flags_ >> 4) != publish_type)
        return fail(Errc::malformed,
                    fmt::format("a packet of type {} and {} bytes, more than the {} a packet may "
                                "have here (only a PUBLISH can be refused in passing)",
                                flags_ >> 4, packet_bytes_, limit_));
    if (qos_of(flags_) == 3) return fail(Errc::malformed, "a PUBLISH of QoS 3 (not MQTT)");
    wanted_ = 2;  // the topic's length first
    state_ = State::hold_publish_start;
    if (remaining_ < wanted_)
        return fail(Errc::malformed, "a PUBLISH whose topic runs past its end (not MQTT)");
    return {};
}

void InboundLimit::publish_start_done(std::vector<std::uint8_t>& out,
                                      std::vector<RefusedPublish>& refused) {
    const int qos = qos_of(flags_);
    const auto topic_end =
        held_.begin() + static_cast<std::ptrdiff_t>(held_.size()) - (qos > 0 ? 2 : 0);
    refused.push_back({std::string(held_.begin() + 2, topic_end), packet_bytes_, qos});
    if (qos > 0) {
        // The same flags and packet identifier on a topic of its own, nothing else: the client
        // answers it as it would have answered the PUBLISH it stands for.
        const auto topic_bytes = refused_publish_topic.size();
        out.push_back(flags_);
        out.push_back(static_cast<std::uint8_t>(2 + topic_bytes + 2));
        out.push_back(0);
        out.push_back(static_cast<std::uint8_t>(topic_bytes));
        out.insert(out.end(), refused_publish_topic.begin(), refused_publish_topic.end());
        out.insert(out.end(), topic_end, held_.end());
    }
    held_.clear();
    state_ = remaining_ > 0 ? State::skip : State::header;
}

}  // namespace ioport::mqtt
