#include "daemon/modbus_server.hpp"

#include <algorithm>
#include <cstring>
#include <new>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

namespace ioport::daemon {
namespace {

using asio::redirect_error;
using asio::use_awaitable;
using asio::ip::tcp;

// Refusals of one address are logged at most this often: a port scanner or a misconfigured HMI
// retrying every second must not flood the log.
constexpr auto refusal_log_interval = 60s;
constexpr std::size_t refusal_log_memory = 1024;
constexpr auto accept_error_pause = 100ms;

std::string describe(const tcp::endpoint& endpoint) {
    const auto address = endpoint.address();
    return address.is_v6() ? fmt::format("[{}]:{}", address.to_string(), endpoint.port())
                           : fmt::format("{}:{}", address.to_string(), endpoint.port());
}

// libmodbus answers function + 0x80, which for a request function code of 0x80 or above wraps
// to a byte without the exception bit (0xFF → 0x7F, a normal-looking response). The exception
// response is the request's function code with its high bit set, whatever the code.
int reply_exception(modbus_t* context, std::span<std::uint8_t> request, unsigned code) {
    request[modbus::mbap_length] &= 0x7F;
    return modbus_reply_exception(context, request.data(), code);
}

struct ModbusFree {
    void operator()(modbus_t* context) const { modbus_free(context); }
};

}  // namespace

struct ModbusServer::Connection {
    Connection(tcp::socket s, std::string name)
        : socket(std::move(s)),
          timer(socket.get_executor()),
          context(modbus_new_tcp(nullptr, 0)),
          peer(std::move(name)) {
        if (!context) throw std::bad_alloc();
        modbus_set_socket(context.get(), socket.native_handle());
    }

    Clock::time_point deadline(std::chrono::microseconds idle_timeout) const {
        if (busy) return Clock::time_point::max();
        if (partial) return frame_started + frame_timeout;
        if (idle_timeout.count() == 0) return Clock::time_point::max();
        return last_activity + idle_timeout;
    }

    // Moves the start of a pipelined or partial request to the front of the buffer.
    void compact() {
        std::memmove(rx.data(), rx.data() + begin, end - begin);
        end -= begin;
        begin = 0;
    }

    void close() {
        if (!open) return;
        open = false;
        boost::system::error_code ignored;
        socket.shutdown(tcp::socket::shutdown_both, ignored);
        socket.close(ignored);
        timer.cancel();
    }

    tcp::socket socket;
    asio::steady_timer timer;  // the watchdog: idle timeout and frame timeout
    std::unique_ptr<modbus_t, ModbusFree> context;
    std::string peer;
    // Pipelined requests are framed from here; larger than a frame so one always fits.
    std::array<std::uint8_t, 4096> rx{};
    std::size_t begin = 0;
    std::size_t end = 0;
    Clock::time_point last_activity = Clock::now();
    Clock::time_point frame_started{};
    Clock::time_point armed = Clock::time_point::max();  // the watchdog's current expiry
    bool partial = false;
    bool busy = false;
    bool open = true;
};

ModbusServer::ModbusServer(const asio::any_io_executor& executor, config::ModbusSettings settings,
                           const std::vector<LinkScheduler*>& units)
    : settings_(std::move(settings)),
      policy_{settings_.read_only, settings_.stale},
      acceptor_(executor),
      accept_retry_(executor),
      scratch_(modbus_mapping_new(gateway::coil_count, 0, gateway::holding_register_count, 0)) {
    if (!scratch_) throw std::bad_alloc();
    for (auto* unit : units)
        units_[static_cast<std::size_t>(unit->config().unit_id)] = unit;
    if (units.size() == 1) units_[0] = units_[255] = units.front();
}

ModbusServer::~ModbusServer() {
    modbus_mapping_free(scratch_);
}

Result<> ModbusServer::start() {
    boost::system::error_code ec;
    const auto address = asio::ip::make_address(settings_.listen_host, ec);
    if (ec)
        return fail(Errc::invalid_argument,
                    fmt::format("modbus.listen: {} is not an IP address", settings_.listen_host));
    const tcp::endpoint endpoint(address, settings_.listen_port);
    const auto where = describe(endpoint);
    acceptor_.open(endpoint.protocol(), ec);
    if (!ec) acceptor_.set_option(tcp::acceptor::reuse_address(true), ec);
    // "[::]:502" takes IPv4 clients too, as ::ffff:a.b.c.d.
    if (!ec && address.is_v6()) acceptor_.set_option(asio::ip::v6_only(false), ec);
    if (!ec) acceptor_.bind(endpoint, ec);
    if (!ec) acceptor_.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) {
        const auto hint = ec == asio::error::address_in_use
                              ? "another program listens there (find it with: ss -ltnp)"
                          : ec == asio::error::access_denied
                              ? "ports below 1024 need CAP_NET_BIND_SERVICE (the packaged "
                                "service has it) or use a port such as 1502"
                              : "check modbus.listen";
        return fail(Errc::io_error,
                    fmt::format("cannot listen on {}: {}: {}", where, ec.message(), hint));
    }
    spdlog::info("Modbus TCP on {}, at most {} clients{}", describe(acceptor_.local_endpoint()),
                 settings_.max_connections, settings_.read_only ? ", read-only" : "");
    asio::co_spawn(acceptor_.get_executor(), accept_loop(), asio::detached);
    return {};
}

void ModbusServer::stop() {
    stopping_ = true;
    boost::system::error_code ignored;
    acceptor_.close(ignored);
    accept_retry_.cancel();
    for (auto* connection : connections_)
        connection->close();
}

tcp::endpoint ModbusServer::local_endpoint() const {
    boost::system::error_code ec;
    return acceptor_.local_endpoint(ec);
}

std::optional<std::string> ModbusServer::refusal(const tcp::endpoint& peer) const {
    if (connections_.size() >= static_cast<std::size_t>(settings_.max_connections))
        return fmt::format("max_connections ({}) reached", settings_.max_connections);
    if (settings_.allow.empty()) return std::nullopt;
    const auto address = peer.address();
    std::array<std::uint8_t, 16> bytes{};
    if (address.is_v4()) {
        const auto v4 = address.to_v4().to_bytes();
        std::copy(v4.begin(), v4.end(), bytes.begin());
    } else {
        bytes = address.to_v6().to_bytes();
    }
    const bool allowed = std::any_of(settings_.allow.begin(), settings_.allow.end(),
                                     [&](const config::Network& network) {
                                         return config::contains(network, bytes, address.is_v6());
                                     });
    if (allowed) return std::nullopt;
    return std::string("not in modbus.allow");
}

void ModbusServer::log_refusal(const asio::ip::address& address, const std::string& why) {
    const auto now = Clock::now();
    const auto key = address.to_string();
    const auto found = refused_logged_.find(key);
    if (found != refused_logged_.end() && now - found->second < refusal_log_interval) return;
    if (refused_logged_.size() >= refusal_log_memory) refused_logged_.clear();
    refused_logged_[key] = now;
    spdlog::warn("refused Modbus client {}: {} (logged once a minute per address)", key, why);
}

asio::awaitable<void> ModbusServer::accept_loop() {
    while (!stopping_) {
        tcp::socket socket(acceptor_.get_executor());
        boost::system::error_code ec;
        co_await acceptor_.async_accept(socket, redirect_error(use_awaitable, ec));
        if (stopping_) break;
        if (ec) {
            // Out of descriptors, say: pause instead of spinning on the same error.
            spdlog::warn("accepting a Modbus client failed: {}", ec.message());
            accept_retry_.expires_after(accept_error_pause);
            co_await accept_retry_.async_wait(redirect_error(use_awaitable, ec));
            continue;
        }
        const auto peer = socket.remote_endpoint(ec);
        if (ec) continue;  // gone already
        if (auto why = refusal(peer)) {
            log_refusal(peer.address(), *why);
            socket.close(ec);
            continue;
        }
        socket.set_option(tcp::no_delay(true), ec);
        socket.set_option(asio::socket_base::keep_alive(true), ec);
        auto connection = std::make_shared<Connection>(std::move(socket), describe(peer));
        connections_.insert(connection.get());
        spdlog::debug("Modbus client {} connected ({} open)", connection->peer,
                      connections_.size());
        asio::co_spawn(acceptor_.get_executor(), serve(connection), asio::detached);
        asio::co_spawn(acceptor_.get_executor(), watch(connection), asio::detached);
    }
}

asio::awaitable<void> ModbusServer::watch(ConnectionPtr c) {
    while (c->open) {
        c->armed = c->deadline(settings_.idle_timeout);
        c->timer.expires_at(c->armed);
        boost::system::error_code ec;
        co_await c->timer.async_wait(redirect_error(use_awaitable, ec));
        if (!c->open) break;
        // Re-armed lazily: activity only moves the deadline, the timer catches up here.
        if (Clock::now() < c->deadline(settings_.idle_timeout)) continue;
        spdlog::debug("Modbus client {}: {}", c->peer,
                      c->partial ? "request not complete within 1 s of its first byte, closed"
                                 : "idle timeout, closed");
        c->close();
    }
}

asio::awaitable<void> ModbusServer::serve(ConnectionPtr c) {
    std::string why = "closed by the client";
    while (c->open) {
        bool completed_frame = false;
        while (c->end - c->begin >= modbus::mbap_length) {
            const auto header =
                modbus::parse_mbap(std::span<const std::uint8_t, modbus::mbap_length>(
                    &c->rx[c->begin], modbus::mbap_length));
            if (auto valid = modbus::check_mbap(header); !valid) {
                why = valid.error().message;
                c->close();
                break;
            }
            const std::size_t total = modbus::mbap_length - 1 + header.length;
            if (c->end - c->begin < total) break;
            c->busy = true;
            const bool keep = co_await handle(*c, {&c->rx[c->begin], total});
            c->busy = false;
            c->last_activity = Clock::now();
            if (!keep) {
                if (c->open) why = "the response could not be sent whole";
                c->close();
                break;
            }
            c->begin += total;
            completed_frame = true;
        }
        if (!c->open) break;
        c->compact();
        const bool was_partial = c->partial && !completed_frame;
        c->partial = c->end > 0;
        if (c->partial && !was_partial) {
            c->frame_started = c->last_activity;
            if (c->frame_started + frame_timeout < c->armed) c->timer.cancel();
        }
        boost::system::error_code ec;
        const auto n = co_await c->socket.async_read_some(
            asio::buffer(c->rx.data() + c->end, c->rx.size() - c->end),
            redirect_error(use_awaitable, ec));
        if (ec) {
            if (c->partial && c->open) why = "connection ended in the middle of a request";
            break;
        }
        c->end += n;
        c->last_activity = Clock::now();
    }
    c->close();
    connections_.erase(c.get());
    spdlog::debug("Modbus client {} disconnected: {}", c->peer, why);
}

asio::awaitable<bool> ModbusServer::handle(Connection& c, std::span<const std::uint8_t> adu) {
    // libmodbus may look past a short request; it only ever sees zeros there.
    std::array<std::uint8_t, modbus::max_adu_length + 4> request{};
    std::memcpy(request.data(), adu.data(), adu.size());
    const int length = static_cast<int>(adu.size());
    auto* context = c.context.get();
    const auto unit_id = adu[modbus::mbap_length - 1];
    auto* unit = units_[unit_id];
    if (!unit) co_return reply_exception(context, request, MODBUS_EXCEPTION_GATEWAY_PATH) > 0;
    auto plan = gateway::plan(unit->state(), policy_, adu.subspan(modbus::mbap_length));
    if (const auto* exception = std::get_if<modbus::Exception>(&plan))
        co_return reply_exception(context, request, static_cast<unsigned>(*exception)) > 0;
    if (const auto* read = std::get_if<gateway::ReadPlan>(&plan))
        co_return modbus_reply(context, request.data(), length, unit->image(read->diagnostics)) > 0;
    const auto failed = co_await unit->write(std::get<gateway::WritePlan>(std::move(plan)));
    if (!c.open) co_return false;
    if (failed) co_return reply_exception(context, request, static_cast<unsigned>(*failed)) > 0;
    co_return modbus_reply(context, request.data(), length, scratch_) > 0;
}

}  // namespace ioport::daemon
