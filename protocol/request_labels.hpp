// The labels under which /metrics counts the Modbus server's responses (gateway.md §5.4):
// ioportd_modbus_requests_total{unit,function} and ioportd_modbus_exceptions_total{unit,code}.
// A client chooses the unit id and the function code of every request, so they are folded:
// only configured unit ids and the function codes of §3.5 are label values of their own, and
// anything else counts under `other`. Otherwise one client could add 65,536 series in a second.
// Exception codes are the server's own (modbus::Exception), folded likewise so that the bound
// holds by construction rather than by what the server happens to answer.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <utility>

#include "protocol/gateway_map.hpp"

namespace ioport::gateway {

// The label value `other`: past every byte, so that it sorts after the numbers.
inline constexpr int other_label = 256;

// `unit_id`: the configured unit (1..247) that answered a request, the single link's also for
// requests to 0 and 255; -1 when no link has the unit id the client asked for.
int unit_label(int unit_id);
// A function code of §3.5 (01-06, 15, 16, 23, 43), or other_label.
int function_label(std::uint8_t function);
// An exception code of modbus::Exception, or other_label.
int exception_label(std::uint8_t code);
// "3", "other".
std::string label_text(int label);

// The Modbus server's one count of its responses: both /metrics families and each unit's
// traffic registers (§5.1) are read from here. Only folded labels are keys, so that however many
// requests of whatever kind arrive, there are at most 248 x 11 request series and 248 x 8
// exception series.
class RequestCounts {
  public:
    using Counts = std::map<std::pair<int, int>, std::uint64_t>;

    // One response (PDU, function code first) of `unit_id` (as unit_label's) to a request of
    // `function`; an exception response also counts under its code.
    void count(int unit_id, std::uint8_t function, std::span<const std::uint8_t> response);
    const Counts& requests() const { return requests_; }      // by (unit, function) label
    const Counts& exceptions() const { return exceptions_; }  // by (unit, code) label
    // The traffic of a configured unit id (the single link's aliases 0 and 255 count as its own).
    const Traffic& traffic(int unit_id) const {
        return traffic_[static_cast<std::size_t>(unit_id) & 0xFF];
    }

  private:
    Counts requests_;
    Counts exceptions_;
    std::array<Traffic, 256> traffic_{};
};

}  // namespace ioport::gateway
