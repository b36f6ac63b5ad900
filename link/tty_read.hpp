// Reading a tty from an event loop without stalling the loop on the kernel.
//
// A read() of a tty whose queue is empty, even a non-blocking one, first waits for the kernel
// worker that hands the driver's input to the tty (the flip buffer: n_tty_read -> flush_work; a
// pty's bytes take the same path). Beside busy loops that worker was seen waiting for a CPU for up
// to 4 s, and Asio's async_read_some tries such a read before it waits for readiness: the whole
// loop stood still meanwhile, every client and timer of it. So a tty is read only when it holds
// input (FIONREAD) or the loop has just found it readable (input, or a hang-up the read reports).
#pragma once

#include <cstddef>

#include "link/asio.hpp"

namespace ioport {

// What the tty on `fd` holds now, read into `buffer` without waiting: 0 when it holds nothing,
// or when `ec` says why the read failed (eof: hung up). `readable`: the loop has just found it
// readable, so it is read at once.
std::size_t read_queued(int fd, asio::mutable_buffer buffer, boost::system::error_code& ec,
                        bool readable = false);

// Waits until `tty` holds input and reads it into `buffer`: async_read_some without the read
// before the wait. 0 only with `ec` set (operation_aborted when cancelled).
asio::awaitable<std::size_t> read_tty(asio::posix::stream_descriptor& tty,
                                      asio::mutable_buffer buffer, boost::system::error_code& ec);

}  // namespace ioport
