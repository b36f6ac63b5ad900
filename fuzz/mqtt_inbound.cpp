// Fuzz target: the bound on what an MQTT 3.1.1 broker sends (protocol/mqtt_inbound.hpp), which
// reads every byte a broker, or whoever sits on the path to it, sends.
//
// Input: byte 0 is the limit (×16 bytes), byte 1 the size of the pieces the stream arrives in
// (1..256); the rest is the stream.
//
// Invariants, from MQTT 3.1.1 §2 and gateway.md §7.5 rather than from the code under test:
// - how the stream is cut into reads changes nothing: the output, the refusals and the verdict
//   are those of the whole stream at once;
// - the output is whole packets, one after the other, each within the limit (or the 22 bytes of
//   a refused PUBLISH's placeholder), plus at most the beginning of one more within the limit;
// - every refusal is of a packet beyond the limit;
// - nothing is invented: the output is never longer than the input, placeholders aside.
#include <cstdint>
#include <span>
#include <vector>

#include "fuzz/fuzz.hpp"
#include "protocol/mqtt_inbound.hpp"

namespace ioport::fuzz {
namespace {

constexpr std::size_t placeholder_bytes = 4 + mqtt::refused_publish_topic.size() + 2;

struct Outcome {
    std::vector<std::uint8_t> out;
    std::vector<mqtt::RefusedPublish> refused;
    bool failed = false;
};

Outcome run(std::size_t limit, std::span<const std::uint8_t> stream, std::size_t piece) {
    mqtt::InboundLimit bound(limit);
    Outcome outcome;
    for (std::size_t at = 0; at < stream.size(); at += piece) {
        const auto n = std::min(piece, stream.size() - at);
        if (!bound.take(stream.subspan(at, n), outcome.out, outcome.refused)) {
            outcome.failed = true;
            break;
        }
    }
    return outcome;
}

void check_packets(std::span<const std::uint8_t> out, std::size_t limit) {
    std::size_t at = 0;
    while (at < out.size()) {
        std::size_t length = 0;
        std::size_t header = 1;
        for (int shift = 0;; shift += 7) {
            if (at + header >= out.size()) return;  // the start of one more
            const auto byte = out[at + header++];
            length |= std::size_t{byte & 0x7fU} << shift;
            if ((byte & 0x80) == 0) break;
        }
        check(header + length <= std::max(limit, placeholder_bytes), "a packet within the limit");
        at += header + length;
    }
}

}  // namespace
}  // namespace ioport::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace ioport::fuzz;
    if (size < 2) return 0;
    const std::size_t limit = std::size_t{data[0]} * 16;
    const std::size_t piece = std::size_t{data[1]} + 1;
    const std::span<const std::uint8_t> stream(data + 2, size - 2);
    const auto whole = run(limit, stream, stream.size() + 1);
    const auto cut = run(limit, stream, piece);
    check(whole.failed == cut.failed, "the verdict does not depend on the reads");
    if (whole.failed) return 0;
    check(whole.out == cut.out, "the output does not depend on the reads");
    check(whole.refused.size() == cut.refused.size(), "nor the refusals");
    std::size_t placeholders = 0;
    for (const auto& refused : whole.refused) {
        check(refused.packet_bytes > limit, "only a packet beyond the limit is refused");
        if (refused.qos > 0) ++placeholders;
    }
    check(whole.out.size() <= stream.size() + placeholders * placeholder_bytes, "nothing invented");
    check_packets(whole.out, limit);
    return 0;
}
