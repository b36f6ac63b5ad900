#include "daemon/modbus_reply.hpp"

#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <new>

#include <fmt/format.h>

namespace ioport::daemon {

UnitImage::UnitImage()
    : mapping_(modbus_mapping_new_start_address(
          0, gateway::coil_count, 0, gateway::discrete_input_count, 0,
          gateway::holding_register_count, 0, gateway::input_register_count)) {
    if (!mapping_) throw std::bad_alloc();
    auto* m = mapping_.get();
    tables_ = {{m->tab_bits, gateway::coil_count},
               {m->tab_input_bits, gateway::discrete_input_count},
               {m->tab_registers, gateway::holding_register_count},
               {m->tab_input_registers, gateway::input_register_count}};
}

Mapping scratch_mapping() {
    Mapping mapping(modbus_mapping_new(gateway::coil_count, 0, gateway::holding_register_count, 0));
    if (!mapping) throw std::bad_alloc();
    return mapping;
}

PaddedRequest::PaddedRequest(std::span<const std::uint8_t> adu)
    : length_(std::min(adu.size(), modbus::max_adu_length)) {
    std::copy_n(adu.begin(), length_, bytes_.begin());
}

Result<std::unique_ptr<ReplyBuilder>> ReplyBuilder::create() {
    // Datagrams keep one response apart from the next; non-blocking so that nothing here can
    // ever wait (a response is at most 260 bytes and is read back before the next is built).
    std::array<int, 2> ends{-1, -1};
    if (::socketpair(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0, ends.data()) != 0)
        return fail(Errc::io_error,
                    fmt::format("cannot create the socket pair for Modbus responses: {}",
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

Result<Bytes> ReplyBuilder::reply(const PaddedRequest& request, modbus_mapping_t* mapping) {
    return take(
        modbus_reply(context_, request.bytes_.data(), static_cast<int>(request.length_), mapping));
}

Result<Bytes> ReplyBuilder::exception(const PaddedRequest& request, modbus::Exception exception) {
    // libmodbus answers function + 0x80, which for a request function code of 0x80 or above
    // wraps to a byte without the exception bit (0xFF → 0x7F, a normal-looking response). It is
    // given a copy with the high bit cleared, so that the sum is the code with the bit set.
    auto bytes = request.bytes_;
    bytes[modbus::mbap_length] &= 0x7F;
    return take(modbus_reply_exception(context_, bytes.data(), static_cast<unsigned>(exception)));
}

Result<Bytes> ReplyBuilder::take(int sent) {
    if (sent <= 0)
        return fail(Errc::io_error, fmt::format("libmodbus could not build the response: {}",
                                                modbus_strerror(errno)));
    Bytes response(MODBUS_TCP_MAX_ADU_LENGTH);
    const auto n = ::recv(our_end_, response.data(), response.size(), MSG_DONTWAIT);
    if (n != sent) {
        // Never expected: drop whatever is left so that the next response is not mixed up with it.
        while (::recv(our_end_, response.data(), response.size(), MSG_DONTWAIT) > 0) {
        }
        return fail(Errc::io_error, fmt::format("a response of {} bytes came back as {}", sent, n));
    }
    response.resize(static_cast<std::size_t>(n));
    return response;
}

}  // namespace ioport::daemon
