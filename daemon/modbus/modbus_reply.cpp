#include "daemon/modbus/modbus_reply.hpp"

#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <new>
#include <optional>

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

namespace {

std::size_t be16(std::span<const std::uint8_t> bytes, std::size_t at) {
    return static_cast<std::size_t>(bytes[at] << 8U | bytes[at + 1]);
}

// The normal response to a read (FC 01-04) inside `mapping`, byte for byte as libmodbus's
// modbus_reply builds it; nothing for any other request, which is left to libmodbus.
std::optional<Bytes> read_response(std::span<const std::uint8_t> adu,
                                   const modbus_mapping_t& mapping) {
    constexpr auto pdu = modbus::mbap_length;
    if (adu.size() != pdu + 5) return std::nullopt;
    const auto function = adu[pdu];
    if (function < 0x01 || function > 0x04) return std::nullopt;
    const std::array<int, 5> starts{0, mapping.start_bits, mapping.start_input_bits,
                                    mapping.start_registers, mapping.start_input_registers};
    const std::array<int, 5> sizes{0, mapping.nb_bits, mapping.nb_input_bits, mapping.nb_registers,
                                   mapping.nb_input_registers};
    const std::array<std::size_t, 5> limits{0, MODBUS_MAX_READ_BITS, MODBUS_MAX_READ_BITS,
                                            MODBUS_MAX_READ_REGISTERS, MODBUS_MAX_READ_REGISTERS};
    const auto address = be16(adu, pdu + 1);
    const auto quantity = be16(adu, pdu + 3);
    const auto start = static_cast<std::size_t>(starts[function]);
    if (quantity == 0 || quantity > limits[function] || address < start ||
        address - start + quantity > static_cast<std::size_t>(sizes[function]))
        return std::nullopt;  // libmodbus's own exception paths
    const auto first = address - start;
    const bool bits = function <= 0x02;
    const std::size_t count = bits ? (quantity + 7) / 8 : quantity * 2;
    Bytes response(pdu + 2 + count);
    std::copy_n(adu.begin(), 2, response.begin());  // the transaction id; protocol id 0
    response[4] = static_cast<std::uint8_t>((3 + count) >> 8U);
    response[5] = static_cast<std::uint8_t>(3 + count);
    response[6] = adu[6];  // the unit id
    response[pdu] = function;
    response[pdu + 1] = static_cast<std::uint8_t>(count);
    auto* data = response.data() + pdu + 2;
    if (bits) {
        const auto* table = function == 0x01 ? mapping.tab_bits : mapping.tab_input_bits;
        for (std::size_t i = 0; i < quantity; ++i)
            if (table[first + i] != 0) data[i / 8] |= static_cast<std::uint8_t>(1U << (i % 8));
    } else {
        const auto* table = function == 0x03 ? mapping.tab_registers : mapping.tab_input_registers;
        for (std::size_t i = 0; i < quantity; ++i) {
            data[2 * i] = static_cast<std::uint8_t>(table[first + i] >> 8U);
            data[2 * i + 1] = static_cast<std::uint8_t>(table[first + i]);
        }
    }
    return response;
}

}  // namespace

Result<Bytes> ReplyBuilder::reply(const PaddedRequest& request, modbus_mapping_t* mapping) {
    // Reads, nearly every request, are built here: libmodbus can only build a response by
    // sending it, which costs two system calls on the socket pair. Writes (each after a serial
    // transaction of a millisecond or more) still go through libmodbus.
    if (auto response = read_response({request.bytes_.data(), request.length_}, *mapping))
        return std::move(*response);
    return take(
        modbus_reply(context_, request.bytes_.data(), static_cast<int>(request.length_), mapping));
}

Result<Bytes> ReplyBuilder::read_back(const PaddedRequest& request, std::uint16_t address,
                                      std::uint16_t quantity, const modbus_mapping_t& mapping) {
    constexpr auto pdu = modbus::mbap_length;
    std::array<std::uint8_t, pdu + 5> read{};
    std::copy_n(request.bytes_.begin(), pdu, read.begin());
    read[4] = 0;
    read[5] = 6;  // unit id and the 5-byte PDU
    read[pdu] = static_cast<std::uint8_t>(modbus::Function::read_holding_registers);
    read[pdu + 1] = static_cast<std::uint8_t>(address >> 8U);
    read[pdu + 2] = static_cast<std::uint8_t>(address);
    read[pdu + 3] = static_cast<std::uint8_t>(quantity >> 8U);
    read[pdu + 4] = static_cast<std::uint8_t>(quantity);
    auto response = read_response(read, mapping);
    if (!response)
        return fail(Errc::invalid_argument,
                    fmt::format("FC 23 read of {} registers at {} is outside the image", quantity,
                                address));
    (*response)[pdu] = static_cast<std::uint8_t>(modbus::Function::read_write_multiple_registers);
    return std::move(*response);
}

Bytes ReplyBuilder::framed(const PaddedRequest& request, std::span<const std::uint8_t> pdu) {
    constexpr auto header = modbus::mbap_length;
    Bytes response(header + pdu.size());
    std::copy_n(request.bytes_.begin(), 2, response.begin());  // the transaction id; protocol 0
    response[4] = static_cast<std::uint8_t>((pdu.size() + 1) >> 8U);
    response[5] = static_cast<std::uint8_t>(pdu.size() + 1);
    response[6] = request.bytes_[6];  // the unit id
    std::copy(pdu.begin(), pdu.end(), response.begin() + header);
    return response;
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
