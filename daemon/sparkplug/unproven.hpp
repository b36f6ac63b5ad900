// Live DDATA the broker has not provably read yet (gateway.md §6.2, docs/sparkplug.md "Nothing
// lost while the broker is away"). Live DDATA goes out at QoS 0: nothing in MQTT says whether the
// broker read it. A broker that stops cleanly stops reading first: what was still in its socket
// then is lost, and it was not stored, as the session was up when it went out. So the edge node
// keeps each live DDATA here, in the order sent, until a later round trip on the same connection
// (a SUBSCRIBE's SUBACK: the broker reads a connection's packets in order) proves the broker read
// it; when the connection is lost, what is still here goes to the store, oldest first, and is
// forwarded after the next births as historical DDATA. One the broker did read but had not
// answered for yet then arrives twice, live and as history, with the same timestamp and value.
//
// Pure bookkeeping: no I/O, no clock. Bounded: beyond max_unproven_bytes the oldest are forgotten
// (counted), as the broker has most likely read the oldest.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "protocol/gateway_map.hpp"
#include "protocol/ioport.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::daemon {

// What the unproven live DDATA may hold in memory (bytes_of's estimate): some 1800 DDATA of an
// analog module (six metrics), or 3900 of one metric. The proofs normally leave a tenth of a
// second's worth here; a broker that went silent (a cable pulled) leaves everything until
// keepalive finds it out, up to 1.5 × keepalive: 45 s of 40 DDATA a second at the default 30 s.
// Encoded, that is less than half of max_store_queue, which takes them at once when the
// connection is lost.
inline constexpr std::size_t max_unproven_bytes = std::size_t{512} << 10;

// One live DDATA as it went out: its device, the time its values were read, and the metrics that
// changed, as indexes into sparkplug::module_metrics(type) with their values (names and wire
// types come from there when it is stored: the same for every device of the type).
struct SentData {
    std::string device;
    std::optional<ModuleType> type;  // nullopt: the ID-2
    std::uint64_t timestamp = 0;     // ms since the Unix epoch
    std::vector<std::pair<std::uint32_t, std::optional<gateway::PointValue>>> points;
};

class UnprovenData {
  public:
    explicit UnprovenData(std::size_t max_bytes = max_unproven_bytes) : max_bytes_(max_bytes) {}

    // A live DDATA went out; its number is mark() from now on.
    void sent(SentData data);
    // The number of the last DDATA sent (0: none yet): what a round trip begun now proves.
    std::uint64_t mark() const { return next_ - 1; }
    // The broker has read every DDATA through number `through`.
    void proven(std::uint64_t through);
    // The connection is lost: every DDATA not proven, oldest first, as store records (metrics by
    // name, each with the DDATA's timestamp); none is kept after.
    std::vector<sparkplug::StoredData> take();

    bool empty() const { return sent_.empty(); }
    std::size_t size() const { return sent_.size(); }
    std::size_t bytes() const { return bytes_; }
    // Forgotten beyond max_bytes, unproven, since the start.
    std::uint64_t forgotten() const { return forgotten_; }

  private:
    struct Entry {
        std::uint64_t number = 0;
        std::size_t bytes = 0;
        SentData data;
    };
    static std::size_t bytes_of(const SentData& data);

    std::size_t max_bytes_;
    std::deque<Entry> sent_;
    std::uint64_t next_ = 1;
    std::size_t bytes_ = 0;
    std::uint64_t forgotten_ = 0;
};

}  // namespace ioport::daemon
