// ioportd's use of libmodbus's server side: the mappings it answers from and the calls that
// build responses. The Modbus server and the fuzz target of the request path both go through
// these, so the fuzzer checks the bytes the daemon really sends.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>

#include <modbus/modbus.h>

#include "protocol/gateway_map.hpp"
#include "protocol/modbus.hpp"

namespace ioport::daemon {

struct MappingFree {
    void operator()(modbus_mapping_t* mapping) const { modbus_mapping_free(mapping); }
};
using Mapping = std::unique_ptr<modbus_mapping_t, MappingFree>;

// A unit's four tables in a libmodbus mapping, so modbus_reply() answers reads straight from it.
class UnitImage {
  public:
    UnitImage();
    modbus_mapping_t* mapping() const { return mapping_.get(); }
    const gateway::Tables& tables() const { return tables_; }

  private:
    Mapping mapping_;
    gateway::Tables tables_;
};

// Where write responses are built: modbus_reply() stores a write's values in the mapping it is
// given, and an image must only ever change when a device confirmed the value.
Mapping scratch_mapping();

// A complete request (MBAP header, unit id, PDU) in a zero-padded buffer. libmodbus reads the
// fields its function code has whatever the request's length, so a short request must only
// ever show it zeros past its end.
class PaddedRequest {
  public:
    // `adu` is at most modbus::max_adu_length bytes (modbus::next_adu never frames more).
    explicit PaddedRequest(std::span<const std::uint8_t> adu);

  private:
    friend int reply(modbus_t*, const PaddedRequest&, modbus_mapping_t*);
    friend int reply_exception(modbus_t*, const PaddedRequest&, modbus::Exception);

    std::array<std::uint8_t, modbus::max_adu_length + 4> bytes_{};
    std::size_t length_ = 0;
};

// The normal response, built by libmodbus from `mapping` (reads take their values from it,
// writes store theirs in it) and sent on the context's socket. The request must be one that
// gateway::plan() accepted, so that libmodbus never takes one of its own exception paths (some
// of which sleep for the response timeout). Returns what modbus_reply does: the bytes sent, or
// -1.
int reply(modbus_t* context, const PaddedRequest& request, modbus_mapping_t* mapping);

// The exception response: the request's function code with its high bit set, whatever the
// code, and `exception`. Returns the bytes sent, or -1.
int reply_exception(modbus_t* context, const PaddedRequest& request, modbus::Exception exception);

}  // namespace ioport::daemon
