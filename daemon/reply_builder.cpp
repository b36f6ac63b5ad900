#include "daemon/reply_builder.hpp"

#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>

#include <fmt/format.h>

namespace ioport::daemon {

Result<std::unique_ptr<ReplyBuilder>> ReplyBuilder::create() {
    // Datagrams keep one reply apart from the next; non-blocking so that nothing here can ever
    // wait (a reply is at most 260 bytes and is read back before the next one is built).
    std::array<int, 2> ends{-1, -1};
    if (::socketpair(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0, ends.data()) != 0)
        return fail(Errc::io_error,
                    fmt::format("cannot create the socket pair for Modbus replies: {}",
                                std::strerror(errno)));
    modbus_t* context = modbus_new_tcp(nullptr, 0);
    if (context == nullptr) {
        ::close(ends[0]);
        ::close(ends[1]);
        return fail(Errc::io_error, "cannot create a libmodbus context");
    }
    modbus_set_socket(context, ends[0]);
    return std::unique_ptr<ReplyBuilder>(new ReplyBuilder(ends[0], ends[1], context));
}

ReplyBuilder::ReplyBuilder(int libmodbus_end, int our_end, modbus_t* context)
    : libmodbus_end_(libmodbus_end), our_end_(our_end), context_(context) {}

ReplyBuilder::~ReplyBuilder() {
    modbus_free(context_);
    ::close(libmodbus_end_);
    ::close(our_end_);
}

Result<Bytes> ReplyBuilder::reply(std::span<const std::uint8_t> request, int length,
                                  modbus_mapping_t* mapping) {
    return take(modbus_reply(context_, request.data(), length, mapping));
}

Result<Bytes> ReplyBuilder::exception(std::span<const std::uint8_t> request, unsigned code) {
    return take(modbus_reply_exception(context_, request.data(), code));
}

Result<Bytes> ReplyBuilder::take(int sent) {
    if (sent <= 0)
        return fail(Errc::io_error,
                    fmt::format("libmodbus could not build the reply: {}", modbus_strerror(errno)));
    Bytes reply(MODBUS_TCP_MAX_ADU_LENGTH);
    const auto n = ::recv(our_end_, reply.data(), reply.size(), MSG_DONTWAIT);
    if (n != sent) {
        // Never expected: drop whatever is left so that the next reply is not mixed up with it.
        while (::recv(our_end_, reply.data(), reply.size(), MSG_DONTWAIT) > 0) {
        }
        return fail(Errc::io_error, fmt::format("a reply of {} bytes came back as {}", sent, n));
    }
    reply.resize(static_cast<std::size_t>(n));
    return reply;
}

}  // namespace ioport::daemon
