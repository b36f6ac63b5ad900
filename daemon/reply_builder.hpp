// Modbus TCP responses built by libmodbus into memory, for the server to write with Asio.
//
// libmodbus can only "reply" by send()ing on its context's socket. Handed a client's TCP socket
// (non-blocking, as Asio keeps it), a client that does not read its responses fills the socket
// buffer and send() writes part of a frame: the client gets a truncated response and the
// connection must be dropped. So libmodbus's socket here is one end of a datagram socketpair:
// each reply is one datagram, read back at once from the other end, and the server writes it to
// the client whole, at the pace the client reads. libmodbus never sees a client's socket, so no
// descriptor, however high, reaches a libmodbus call, and nothing of libmodbus waits on a client.
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include <modbus/modbus.h>

#include "protocol/error.hpp"

namespace ioport::daemon {

using Bytes = std::vector<std::uint8_t>;

class ReplyBuilder {
  public:
    // Fails when the socketpair or the libmodbus context cannot be made (out of descriptors).
    static Result<std::unique_ptr<ReplyBuilder>> create();
    ~ReplyBuilder();
    ReplyBuilder(const ReplyBuilder&) = delete;
    ReplyBuilder& operator=(const ReplyBuilder&) = delete;

    // `request`: a complete ADU in a zero-padded buffer (libmodbus may look past a short one),
    // `length` its real length. The request must have passed gateway::plan: libmodbus's own
    // exception paths for bad quantities sleep and flush its socket.
    Result<Bytes> reply(std::span<const std::uint8_t> request, int length,
                        modbus_mapping_t* mapping);
    Result<Bytes> exception(std::span<const std::uint8_t> request, unsigned code);

  private:
    ReplyBuilder(int libmodbus_end, int our_end, modbus_t* context);
    Result<Bytes> take(int sent);

    int libmodbus_end_;  // libmodbus sends here
    int our_end_;        // and the reply is read back here
    modbus_t* context_;
};

}  // namespace ioport::daemon
