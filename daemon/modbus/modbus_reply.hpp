// ioportd's use of libmodbus's server side: the mappings it answers from and the builder of
// responses. The Modbus server and the fuzz target of the request path both go through these,
// so the fuzzer checks the bytes the daemon really sends.
//
// libmodbus can only "reply" by send()ing on its context's socket. Handed a client's TCP socket
// (non-blocking, as Asio keeps it), a client that does not read its responses fills the socket
// buffer and send() writes part of a frame: the client gets a truncated response and the
// connection must be dropped. So libmodbus's socket here is one end of a datagram socketpair:
// each response it builds is one datagram, read back at once from the other end, and the server
// writes it to the client whole, at the pace the client reads. libmodbus never sees a client's
// socket, so no descriptor, however high, reaches a libmodbus call that selects, and nothing of
// libmodbus waits on a client.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include <modbus/modbus.h>

#include "protocol/error.hpp"
#include "protocol/gateway_map.hpp"
#include "protocol/modbus.hpp"

namespace ioport::daemon {

using Bytes = std::vector<std::uint8_t>;

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
    friend class ReplyBuilder;

    std::array<std::uint8_t, modbus::max_adu_length + 4> bytes_{};
    std::size_t length_ = 0;
};

class ReplyBuilder {
  public:
    // Fails when the socketpair or the libmodbus context cannot be made (out of descriptors).
    static Result<std::unique_ptr<ReplyBuilder>> create();
    ~ReplyBuilder();
    ReplyBuilder(const ReplyBuilder&) = delete;
    ReplyBuilder& operator=(const ReplyBuilder&) = delete;

    // The normal response from `mapping`: reads take their values from it (built here, byte for
    // byte as libmodbus would), writes store theirs in it (built by libmodbus). The request must be
    // one that gateway::plan() accepted, so that libmodbus never takes one of its own exception
    // paths (some of which sleep for the response timeout and flush the socket).
    Result<Bytes> reply(const PaddedRequest& request, modbus_mapping_t* mapping);

    // The exception response: the request's function code with its high bit set, whatever the
    // code, and `exception`.
    Result<Bytes> exception(const PaddedRequest& request, modbus::Exception exception);

    // FC 23's response once its write is done: `quantity` holding registers from `address` in
    // `mapping`, as FC 03 reads them, under function code 23.
    static Result<Bytes> read_back(const PaddedRequest& request, std::uint16_t address,
                                   std::uint16_t quantity, const modbus_mapping_t& mapping);
    // A response whose PDU was built elsewhere (FC 43): the request's MBAP header around it.
    static Bytes framed(const PaddedRequest& request, std::span<const std::uint8_t> pdu);

  private:
    ReplyBuilder(int libmodbus_end, int our_end, modbus_t* context);
    Result<Bytes> take(int sent);

    int libmodbus_end_;  // libmodbus sends here
    int our_end_;        // and the response is read back here
    modbus_t* context_;
};

}  // namespace ioport::daemon
