#include "daemon/modbus/modbus_server.hpp"

#include <linux/sockios.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/ioctl.h>

#include <algorithm>
#include <cstring>

#include <fmt/format.h>
#include <openssl/ssl.h>

#include "config/duration.hpp"
#include "daemon/base/file_descriptors.hpp"
#include "daemon/base/listener.hpp"
#include "protocol/device_identification.hpp"

namespace ioport::daemon {
namespace {

using asio::redirect_error;
using asio::use_awaitable;
using asio::ip::tcp;

constexpr auto accept_error_pause = 100ms;
// After `keepalive` of silence a client is probed this many times, keepalive / probes apart: one
// that vanished (power cut, cable pulled) is closed within twice `keepalive`.
constexpr int keepalive_probes = 3;

// Calls `f` when it goes out of scope, however that happens.
template <class F>
class AtExit {
  public:
    explicit AtExit(F f) : f_(std::move(f)) {}
    ~AtExit() { f_(); }
    AtExit(const AtExit&) = delete;
    AtExit& operator=(const AtExit&) = delete;

  private:
    F f_;
};

// A TCP-level integer option, as Asio's SettableSocketOption requirements describe one: Asio
// names the portable options only.
template <int Name>
class TcpOption {
  public:
    explicit TcpOption(int value) : value_(value) {}
    int level(const tcp& /*protocol*/) const { return IPPROTO_TCP; }
    int name(const tcp& /*protocol*/) const { return Name; }
    const void* data(const tcp& /*protocol*/) const { return &value_; }
    std::size_t size(const tcp& /*protocol*/) const { return sizeof(value_); }

  private:
    int value_;
};
using KeepaliveIdle = TcpOption<TCP_KEEPIDLE>;
using KeepaliveInterval = TcpOption<TCP_KEEPINTVL>;
using KeepaliveProbes = TcpOption<TCP_KEEPCNT>;

}  // namespace

struct ModbusServer::Connection {
    Connection(tcp::socket s, const tcp::endpoint& from, TlsContext context)
        : plain(std::move(s)),
          timer(plain.get_executor()),
          address(from.address()),
          peer(host_port(from)),
          tls_context(std::move(context)),
          handshaking(tls_context != nullptr) {
        if (tls_context) tls = make_tls_stream(std::move(plain), *tls_context);
    }

    tcp::socket& socket() { return tls ? tls->next_layer() : plain; }

    Clock::time_point deadline(std::chrono::microseconds idle_timeout) const {
        if (handshaking) return accepted + tls_handshake_timeout;
        if (sending) return drained + send_timeout;
        if (busy) return Clock::time_point::max();
        if (partial) return frame_started + frame_timeout;
        if (idle_timeout.count() == 0) return Clock::time_point::max();
        return last_activity + idle_timeout;
    }

    // Whether the client took data since it was last seen to: the bytes it has not
    // acknowledged (SIOCOUTQ) are none, or fewer by a few KB. Whether the socket accepts more is
    // no measure (the kernel takes small writes into its buffers long after the client's window
    // shut), and neither is any decrease: a client's kernel that compacts its receive queue
    // acknowledges a KB or so now and then while the client reads nothing.
    bool client_took_data() {
        int bytes = 0;
        if (::ioctl(socket().native_handle(), SIOCOUTQ, &bytes) != 0) return true;
        if (unacknowledged < 0) {  // no baseline yet (a TLS response): this is it
            unacknowledged = bytes;
            drained = Clock::now();
            return true;
        }
        const bool took = bytes == 0 || bytes + reading_evidence <= unacknowledged;
        if (took || bytes > unacknowledged) unacknowledged = bytes;
        if (took) drained = Clock::now();
        return took;
    }
    static constexpr int reading_evidence = 4096;

    // Whether the socket holds no byte the client has not acknowledged. Asio's TLS engine writes
    // a record synchronously only whole (a would_block part way would lose the rest of it), and
    // the kernel takes a record of a few hundred bytes whole into an empty socket buffer: so a
    // TLS response is written at once only then, else by an asynchronous operation.
    bool nothing_queued() {
        int bytes = 0;
        return ::ioctl(socket().native_handle(), SIOCOUTQ, &bytes) == 0 && bytes == 0;
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
        // Closed without a close_notify, OpenSSL would take the session for a broken one and
        // drop it from the cache: the client could not resume it.
        if (tls) SSL_set_shutdown(tls->native_handle(), SSL_SENT_SHUTDOWN);
        boost::system::error_code ignored;
        socket().shutdown(tcp::socket::shutdown_both, ignored);
        socket().close(ignored);
        timer.cancel();
    }

    tcp::socket plain;         // moved into `tls` for a TLS connection
    asio::steady_timer timer;  // the watchdog: handshake, idle, frame and send timeouts
    asio::ip::address address;
    std::string peer;
    // TLS: the context it was accepted with (kept: a reload may replace the listener's), the
    // stream over the socket, and what the client may do, decided at the handshake.
    TlsContext tls_context;
    std::unique_ptr<TlsStream> tls;
    modbus_security::Rights rights;
    bool handshaking = false;
    bool refusal_logged = false;  // a request its role does not allow: logged once
    Clock::time_point accepted = Clock::now();
    // Pipelined requests are framed from here; larger than a frame so one always fits.
    std::array<std::uint8_t, 4096> rx{};
    std::size_t begin = 0;
    std::size_t end = 0;
    Clock::time_point last_activity = Clock::now();
    Clock::time_point frame_started{};
    Clock::time_point drained = Clock::now();  // the client was last seen taking data
    int unacknowledged = 0;  // SIOCOUTQ at the last look; -1: none taken yet (TLS)
    Clock::time_point armed = Clock::time_point::max();  // the watchdog's current expiry
    bool partial = false;
    bool busy = false;     // a request is being decided (a write waits for the device)
    bool sending = false;  // its response is being written
    bool open = true;
    std::chrono::system_clock::time_point since = std::chrono::system_clock::now();
    std::uint64_t requests = 0;
};

ModbusServer::ModbusServer(const asio::any_io_executor& executor, config::ModbusSettings settings,
                           const Links& links, Log& log, EventBus& bus,
                           std::shared_ptr<CommLossWatch> comm_loss)
    : executor_(executor),
      settings_(std::move(settings)),
      policy_{settings_.read_only, settings_.stale},
      log_(log),
      bus_(bus),
      accept_retry_(executor),
      scratch_(scratch_mapping()),
      comm_loss_(std::move(comm_loss)) {
    set_units(links);
}

// A link that stays (and the word order with it) keeps its unit and image; a new or restarted
// one gets a unit of its own, filled from what the link knows.
void ModbusServer::set_units(const Links& links) {
    ports_ = links.size();
    std::array<std::shared_ptr<ModbusUnit>, 256> units{};
    for (const auto& link : links) {
        const auto id = static_cast<std::size_t>(link->config().unit_id);
        auto& unit = units[id];
        if (const auto& old = units_[id];
            old && old->link_ptr() == link && old->word_order() == settings_.word_order)
            unit = old;
        else
            unit = std::make_shared<ModbusUnit>(link, settings_.word_order);
    }
    if (links.size() == 1)
        units[0] = units[255] = units[static_cast<std::size_t>(links.front()->config().unit_id)];
    units_ = std::move(units);
}

ModbusServer::~ModbusServer() = default;

ModbusServer::Listener& ModbusServer::listener(Transport transport) {
    switch (transport) {
        case Transport::tcp:
            return plain_;
        case Transport::tls:
            return tls_;
    }
    return plain_;
}

bool ModbusServer::same_address(const config::ModbusSettings& a, const config::ModbusSettings& b,
                                Transport transport) {
    switch (transport) {
        case Transport::tcp:
            return a.listen_host == b.listen_host && a.listen_port == b.listen_port;
        case Transport::tls:
            return a.tls && b.tls && a.tls->listen_host == b.tls->listen_host &&
                   a.tls->listen_port == b.tls->listen_port;
    }
    return false;
}

Result<Acceptor> ModbusServer::listen(const config::ModbusSettings& settings, Transport transport) {
    switch (transport) {
        case Transport::tcp:
            return listen_tcp(executor_, settings.listen_host, settings.listen_port,
                              "modbus.listen");
        case Transport::tls:
            return listen_tcp(executor_, settings.tls->listen_host, settings.tls->listen_port,
                              "modbus.tls.listen");
    }
    return fail(Errc::invalid_argument, "no such transport");
}

Result<> ModbusServer::start() {
    auto replies = ReplyBuilder::create();
    if (!replies) return Unexpected(replies.error());
    replies_ = std::move(*replies);
    make_room();
    // As a reload from nothing: both listeners bound, or neither.
    config::ModbusSettings none;
    none.listen_host.clear();
    const auto settings = std::exchange(settings_, none);
    auto prepared = prepare(settings);
    settings_ = settings;
    if (!prepared) return prepared;
    for (const auto transport : {Transport::tcp, Transport::tls})
        apply(settings_, transport);
    if (!plain_.acceptor && !tls_.acceptor)
        log_.warn({}, "no Modbus listener: modbus.listen is \"\" and modbus.tls has no listen");
    last_request_ = Clock::now();
    return {};
}

void ModbusServer::note_request(Clock::time_point at, bool contact) {
    since_previous_ =
        std::max(std::chrono::microseconds{0},
                 std::chrono::duration_cast<std::chrono::microseconds>(at - last_request_));
    last_request_ = at;
    if (contact) comm_loss_->contact(at);
}

void ModbusServer::answered_request(bool contact) {
    if (!contact) return;
    comm_loss_->answered();  // the first request after a loss read 1020 as 1; later ones read 0
}

// Only a request the gateway could serve shows that a SCADA is there: a client probing unknown
// units, or one without the rights for what it asks, must not hold the outputs out of their
// safe state (gateway.md §5.3).
bool ModbusServer::keeps_contact(const Connection& c, std::span<const std::uint8_t> adu) const {
    const auto& unit = units_[adu[modbus::mbap_length - 1]];
    if (!unit) return false;
    return !c.tls || modbus_security::permits(c.rights, unit->link().config().unit_id,
                                              adu[modbus::mbap_length]);
}

int ModbusServer::counted_unit(std::span<const std::uint8_t> adu) const {
    const auto& unit = units_[adu[modbus::mbap_length - 1]];
    return unit ? unit->link().config().unit_id : -1;
}

void ModbusServer::store_front(ModbusUnit& unit) const {
    const auto& traffic = stats_.responses.traffic(unit.link().config().unit_id);
    gateway::store_front(unit.tables(),
                         {traffic, connections(), since_previous_, comm_loss_->lost()},
                         settings_.word_order);
}

void ModbusServer::make_room() {
    // A connection in its handshake holds a descriptor beside the max_connections clients.
    const auto handshakes =
        settings_.tls ? static_cast<std::size_t>(settings_.tls->max_handshakes) : 0;
    const auto room = make_room_for_clients(static_cast<std::size_t>(settings_.max_connections),
                                            ports_ + handshakes);
    max_clients_ = room.clients;
    if (room.shortfall)
        log_.warn({}, "{}", *room.shortfall);
    else if (room.raised)
        log_.info({}, "file descriptor limit raised to {} for max_connections {}", room.soft_limit,
                  settings_.max_connections);
}

void ModbusServer::close(Listener& listener) {
    if (!listener.acceptor) return;
    boost::system::error_code ignored;
    listener.acceptor->close(ignored);
    listener.acceptor.reset();
}

void ModbusServer::accept_on(Transport transport, Acceptor acceptor) {
    auto& l = listener(transport);
    if (l.acceptor) accept_retry_.cancel();
    close(l);
    l.acceptor = std::move(acceptor);
    boost::system::error_code ec;
    const auto where = host_port(l.acceptor->local_endpoint(ec));
    const char* read_only = settings_.read_only ? ", read-only" : "";
    switch (transport) {
        case Transport::tcp:
            log_.info({}, "Modbus TCP on {}, at most {} clients{}", where,
                      settings_.max_connections, read_only);
            break;
        case Transport::tls:
            log_.info({},
                      "Modbus/TCP Security (TLS) on {}, at most {} clients{}, roles {}; at most {} "
                      "handshakes at once, {} per address{}",
                      where, settings_.max_connections, read_only,
                      modbus_security::names(settings_.tls->roles), settings_.tls->max_handshakes,
                      config::per_address_handshakes,
                      settings_.tls->client_crl.empty() ? "" : ", revocations from client_crl");
            break;
    }
    spawn("accepting Modbus clients",
          [this, transport, acceptor = l.acceptor] { return accept_loop(transport, acceptor); });
}

void ModbusServer::abandon() {
    for (auto* l : {&plain_, &tls_}) {
        l->next.reset();
        l->next_context.reset();
    }
}

Result<> ModbusServer::prepare(const config::ModbusSettings& next) {
    abandon();  // what an earlier prepare() left
    auto prepared = prepare(next, Transport::tcp);
    if (prepared) prepared = prepare(next, Transport::tls);
    if (!prepared) plain_.next.reset();  // the new plain address is not kept bound either
    return prepared;
}

Result<> ModbusServer::prepare(const config::ModbusSettings& next, Transport transport) {
    auto& l = listener(transport);
    const bool wanted = transport == Transport::tcp ? next.plain() : next.tls.has_value();
    if (!wanted) return {};
    if (transport == Transport::tls &&
        (!settings_.tls || !tls_.context ||
         settings_.tls->certificate_pem != next.tls->certificate_pem ||
         settings_.tls->key_pem != next.tls->key_pem ||
         settings_.tls->client_ca_pem != next.tls->client_ca_pem ||
         settings_.tls->client_crl_pem != next.tls->client_crl_pem)) {
        auto context = make_tls_context(*next.tls);
        if (!context) return Unexpected(context.error());
        l.next_context = std::move(*context);
    }
    if (l.acceptor && same_address(settings_, next, transport)) return {};
    auto acceptor = listen(next, transport);
    if (!acceptor) return Unexpected(acceptor.error());
    l.next = std::move(*acceptor);
    return {};
}

// `settings_` is `next` already: the listener's log line tells the new limits.
void ModbusServer::apply(const config::ModbusSettings& next, Transport transport) {
    auto& l = listener(transport);
    if (l.next_context) l.context = std::exchange(l.next_context, nullptr);
    if (l.next) {
        accept_on(transport, std::exchange(l.next, nullptr));
        return;
    }
    const bool wanted = transport == Transport::tcp ? next.plain() : next.tls.has_value();
    if (!wanted && l.acceptor) {
        log_.info({}, "{} listener closed",
                  transport == Transport::tcp ? "Modbus TCP" : "Modbus/TCP Security (TLS)");
        close(l);
        l.context.reset();
    }
}

void ModbusServer::apply(config::ModbusSettings next, const Links& links) {
    settings_ = std::move(next);
    policy_ = {settings_.read_only, settings_.stale};
    set_units(links);
    make_room();
    for (const auto transport : {Transport::tcp, Transport::tls})
        apply(settings_, transport);
    for (auto* connection : connections_) {
        if (!allowed(connection->address)) {
            log_.info({.client = connection->peer},
                      "Modbus client {} closed: not in the reloaded modbus.allow",
                      connection->peer);
            connection->close();
        } else {
            connection->timer.cancel();  // re-armed with the new idle_timeout
        }
    }
    close_revoked();
}

void ModbusServer::close_revoked() {
    if (!tls_.context) return;
    for (auto* connection : connections_) {
        if (!connection->tls || connection->handshaking || !connection->open) continue;
        const auto serial = revoked_serial(*tls_.context, *connection->tls);
        if (!serial) continue;
        auto text = fmt::format(
            "Modbus/TCP Security client {} ({}) closed: its certificate (serial {}) is revoked by "
            "the reloaded modbus.tls.client_crl",
            connection->peer, tls_peer(*connection->tls).subject, *serial);
        log_.warn({.client = connection->peer}, "{}", text);
        bus_.publish(
            Note{.kind = EventKind::client_refused, .client = connection->peer, .text = text});
        connection->close();
    }
}

void ModbusServer::shut_down() {
    stopping_ = true;
    boost::system::error_code ignored;
    for (auto* l : {&plain_, &tls_}) {
        close(*l);
        if (l->next) l->next->close(ignored);
    }
    accept_retry_.cancel();
    for (auto* connection : connections_)
        if (!connection->busy && !connection->sending) connection->close();
}

void ModbusServer::stop() {
    shut_down();
    for (auto* connection : connections_)
        connection->close();
}

tcp::endpoint ModbusServer::local_endpoint() const {
    boost::system::error_code ec;
    return plain_.acceptor ? plain_.acceptor->local_endpoint(ec) : tcp::endpoint();
}

tcp::endpoint ModbusServer::tls_endpoint() const {
    boost::system::error_code ec;
    return tls_.acceptor ? tls_.acceptor->local_endpoint(ec) : tcp::endpoint();
}

std::vector<ClientView> ModbusServer::clients() const {
    std::vector<ClientView> views;
    views.reserve(connections_.size());
    for (const auto* connection : connections_)
        if (!connection->handshaking)
            views.push_back({connection->peer, connection->since, connection->requests,
                             connection->tls != nullptr, connection->rights.role});
    std::ranges::sort(views, {}, &ClientView::since);
    return views;
}

std::string ModbusServer::too_many() const {
    return max_clients_ < static_cast<std::size_t>(settings_.max_connections)
               ? fmt::format("out of file descriptors for more than {} clients", max_clients_)
               : fmt::format("max_connections ({}) reached", settings_.max_connections);
}

namespace {

// Of one client, whether it arrives over IPv4 or as ::ffff:a.b.c.d on an IPv6 socket.
asio::ip::address handshake_key(const asio::ip::address& address) {
    if (address.is_v6() && address.to_v6().is_v4_mapped())
        return asio::ip::make_address_v4(asio::ip::v4_mapped, address.to_v6());
    return address;
}

}  // namespace

// A TLS client's handshake is checked against the handshake budget only: those in progress never
// take the places of the clients served (gateway.md §5.6), which the handshake's end checks.
std::optional<ModbusServer::Refusal> ModbusServer::refusal(const tcp::endpoint& peer,
                                                           Transport transport) {
    if (connections() >= max_clients_) return Refusal{&stats_.refused_too_many, too_many()};
    if (!allowed(peer.address()))
        return Refusal{&stats_.refused_not_allowed, "not in modbus.allow"};
    if (transport == Transport::tcp) return std::nullopt;
    const auto budget = settings_.tls ? static_cast<std::size_t>(settings_.tls->max_handshakes) : 0;
    if (handshakes_ >= budget)
        return Refusal{&stats_.refused_too_many_handshakes,
                       fmt::format("tls.max_handshakes ({}) TLS handshakes in progress", budget)};
    const auto found = handshakes_by_address_.find(handshake_key(peer.address()));
    if (found != handshakes_by_address_.end() && found->second >= config::per_address_handshakes)
        return Refusal{&stats_.refused_too_many_handshakes,
                       fmt::format("{} TLS handshakes of this address in progress",
                                   config::per_address_handshakes)};
    return std::nullopt;
}

void ModbusServer::begin_handshake(Connection& c) {
    ++handshakes_;
    ++handshakes_by_address_[handshake_key(c.address)];
}

void ModbusServer::end_handshake(Connection& c) {
    if (!std::exchange(c.handshaking, false)) return;
    --handshakes_;
    const auto found = handshakes_by_address_.find(handshake_key(c.address));
    if (found != handshakes_by_address_.end() && --found->second <= 0)
        handshakes_by_address_.erase(found);
}

bool ModbusServer::allowed(const asio::ip::address& address) const {
    return daemon::allowed(settings_.allow, address);
}

void ModbusServer::log_refusal(const asio::ip::address& address, const std::string& why) {
    const auto now = Clock::now();
    const auto client = address.to_string();
    // By address and reason: one address may have several problems (an expired certificate on
    // one HMI, a missing one on another), each worth its line.
    const auto held = refusals_.admit(fmt::format("{} {}", client, why), now);
    if (!held) return;
    log_.warn({.client = client},
              "refused Modbus client {}: {} (logged once a minute per address and reason){}",
              client, why, held_back(*held));
    bus_.publish(Note{.kind = EventKind::client_refused,
                      .client = client,
                      .text = fmt::format("refused Modbus client {}: {}", client, why)});
}

// Keepalive reaps clients that vanished without a FIN: their connection would otherwise hold a
// max_connections place for ever when idle_timeout is 0.
void ModbusServer::configure(tcp::socket& socket) const {
    boost::system::error_code ec;
    socket.set_option(tcp::no_delay(true), ec);
    socket.non_blocking(true, ec);  // responses are written at once where the socket takes them
    if (settings_.keepalive.count() == 0) return;
    const auto idle = static_cast<int>(std::max<std::int64_t>(
        1, std::chrono::duration_cast<std::chrono::seconds>(settings_.keepalive).count()));
    socket.set_option(asio::socket_base::keep_alive(true), ec);
    socket.set_option(KeepaliveIdle(idle), ec);
    socket.set_option(KeepaliveInterval(std::max(1, idle / keepalive_probes)), ec);
    socket.set_option(KeepaliveProbes(keepalive_probes), ec);
}

asio::awaitable<void> ModbusServer::accept_loop(Transport transport, Acceptor acceptor) {
    while (acceptor->is_open()) {
        tcp::socket socket(executor_);
        boost::system::error_code ec;
        co_await acceptor->async_accept(socket, redirect_error(use_awaitable, ec));
        if (!acceptor->is_open()) break;  // shut down, or replaced by a reload
        if (ec) {
            // Out of descriptors, say: pause instead of spinning on the same error.
            log_.warn({}, "accepting a Modbus client failed: {}", ec.message());
            accept_retry_.expires_after(accept_error_pause);
            co_await accept_retry_.async_wait(redirect_error(use_awaitable, ec));
            continue;
        }
        const auto peer = socket.remote_endpoint(ec);
        if (ec) continue;  // gone already
        if (auto refused = refusal(peer, transport)) {
            ++*refused->counted;
            log_refusal(peer.address(), refused->why);
            socket.close(ec);
            continue;
        }
        configure(socket);
        auto connection = std::make_shared<Connection>(
            std::move(socket), peer, transport == Transport::tls ? tls_.context : nullptr);
        connections_.insert(connection.get());
        if (connection->handshaking) begin_handshake(*connection);
        log_.debug({.client = connection->peer}, "Modbus client {} connected ({} open)",
                   connection->peer, connections_.size());
        spawn("serving a Modbus client", [this, connection] { return serve(connection); });
        spawn("watching a Modbus client", [this, connection] { return watch(connection); });
    }
}

// The server is kept alive by every coroutine of its own, as the HTTP server and the links are:
// a reload or a stop may let go of it while a connection still finishes. An exception that
// escapes one is a bug, logged rather than lost; what it held is released by its destructors.
void ModbusServer::spawn(std::string_view what, std::function<asio::awaitable<void>()> coroutine) {
    asio::co_spawn(
        executor_,
        [self = shared_from_this(), coroutine = std::move(coroutine)] { return coroutine(); },
        [self = shared_from_this(), what = std::string(what)](const std::exception_ptr& error) {
            if (!error) return;
            try {
                std::rethrow_exception(error);
            } catch (const std::exception& e) {
                self->log_.error({}, "{} failed: {}", what, e.what());
            }
        });
}

asio::awaitable<void> ModbusServer::watch(ConnectionPtr c) {
    while (c->open) {
        // At most send_timeout ahead, so that a response that begins to wait is always watched
        // in time without re-arming the timer for each one.
        c->armed = std::min(c->deadline(settings_.idle_timeout), Clock::now() + send_timeout);
        c->timer.expires_at(c->armed);
        boost::system::error_code ec;
        co_await c->timer.async_wait(redirect_error(use_awaitable, ec));
        if (!c->open) break;
        // Re-armed lazily: activity only moves the deadline, the timer catches up here.
        if (Clock::now() < c->deadline(settings_.idle_timeout)) continue;
        // A slow reader may leave the socket unwritable for long: it still reads.
        if (c->sending && c->client_took_data()) continue;
        log_.debug({.client = c->peer}, "Modbus client {}: {}", c->peer,
                   c->handshaking ? "TLS handshake not complete within 5 s, closed"
                   : c->sending   ? "it read nothing for 5 s while a response waited, closed"
                   : c->partial   ? "request not complete within 1 s of its first byte, closed"
                                  : "idle timeout, closed");
        c->close();
    }
}

// The rest of a response the socket did not take at once (every TLS response), whole, at the
// client's pace: while it does not read, nothing more is read from it either, and the watchdog
// closes it once it has taken no data for send_timeout. The watchdog wakes by drained +
// send_timeout, as it is never armed further ahead.
asio::awaitable<boost::system::error_code> ModbusServer::send_rest(
    Connection& c, std::span<const std::uint8_t> rest) {
    c.sending = true;
    c.drained = Clock::now();
    // The baseline the watchdog compares with. A TLS response nearly always goes out at once,
    // so its baseline is taken by the watchdog's first look, should the response still wait
    // then: a client that stopped reading is closed 5 to 10 s into the wait, not 5.
    if (c.tls)
        c.unacknowledged = -1;
    else
        c.client_took_data();
    boost::system::error_code ec;
    const auto buffer = asio::buffer(rest.data(), rest.size());
    if (c.tls)
        co_await asio::async_write(*c.tls, buffer, redirect_error(use_awaitable, ec));
    else
        co_await asio::async_write(c.plain, buffer, redirect_error(use_awaitable, ec));
    c.sending = false;
    co_return ec;
}

asio::awaitable<std::size_t> ModbusServer::read_some(Connection& c, boost::system::error_code& ec) {
    const auto buffer = asio::buffer(c.rx.data() + c.end, c.rx.size() - c.end);
    if (c.tls) co_return co_await c.tls->async_read_some(buffer, redirect_error(use_awaitable, ec));
    co_return co_await c.plain.async_read_some(buffer, redirect_error(use_awaitable, ec));
}

asio::awaitable<bool> ModbusServer::handshake(Connection& c) {
    boost::system::error_code ec;
    co_await c.tls->async_handshake(asio::ssl::stream_base::server,
                                    redirect_error(use_awaitable, ec));
    end_handshake(c);
    if (stopping_) co_return false;
    // A client without a valid certificate retries, maybe every second, and a scanner holds
    // places: refusals, logged once a minute per address and reason.
    if (!c.open || ec) {
        ++stats_.refused_tls_handshake;
        log_refusal(c.address, !c.open
                                   ? std::string("TLS handshake not complete within 5 s")
                                   : fmt::format("TLS handshake failed: {}",
                                                 handshake_failure(ec, c.tls->native_handle())));
        co_return false;
    }
    // Handshakes in progress were not counted against max_connections: several may end together.
    if (connections() > max_clients_) {
        ++stats_.refused_too_many;
        log_refusal(c.address, too_many());
        co_return false;
    }
    const bool resumed = SSL_session_reused(c.tls->native_handle()) != 0;
    // Against the CRL of now: the connection's context may be older than the last reload.
    if (const auto serial = tls_.context ? revoked_serial(*tls_.context, *c.tls) : std::nullopt) {
        ++stats_.refused_tls_handshake;
        log_refusal(c.address, fmt::format("TLS {}: certificate revoked (serial {}) by "
                                           "modbus.tls.client_crl",
                                           resumed ? "session resumed" : "handshake", *serial));
        co_return false;
    }
    c.last_activity = Clock::now();
    const auto peer = tls_peer(*c.tls);
    // Taken from the settings in place: a ternary with an empty Roles{} copied the map per
    // handshake. A reload that removed modbus.tls during the handshake leaves no roles to give.
    c.rights = settings_.tls
                   ? modbus_security::rights_of(peer.role, settings_.tls->default_role,
                                                settings_.tls->roles)
                   : modbus_security::Rights{{}, std::nullopt, "modbus.tls is off: no rights"};
    const TlsIdentity identity{peer.subject, c.rights.role};
    log_.info({.client = c.peer, .tls = &identity},
              "Modbus/TCP Security client {} ({}, TLS {}{}): {}", c.peer, peer.subject,
              SSL_get_version(c.tls->native_handle()), resumed ? ", resumed" : "", c.rights.why);
    co_return true;
}

// However serve ends (an exception included), the connection leaves the set that shut_down()
// and the pages walk.
void ModbusServer::forget(Connection& c) {
    c.close();
    end_handshake(c);
    connections_.erase(&c);
}

// Nearly always the socket takes a response at once: written then and there, without an
// asynchronous operation and its completion (nor a coroutine frame). What it did not take is
// send_rest()'s.
std::size_t ModbusServer::write_now(Connection& c, const Bytes& response,
                                    boost::system::error_code& ec) {
    std::size_t written = 0;
    if (!c.tls)
        written = c.plain.write_some(asio::buffer(response), ec);
    else if (c.nothing_queued())
        written = c.tls->write_some(asio::buffer(response), ec);
    if (ec == asio::error::would_block) ec = {};
    return written;
}

// GCC 12 reports Asio's coroutine frame, allocated and freed by awaitable_frame_base's own
// operator new and delete, as a mismatched new/delete (GCC bug 109224), or not, depending on
// unrelated members of this class. Nothing here allocates by hand.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif
asio::awaitable<void> ModbusServer::serve(ConnectionPtr c) {
    const AtExit forget_it([this, &c] { forget(*c); });
    std::string why = "closed by the client";
    if (c->tls && !co_await handshake(*c)) {
        why = "no TLS session";
        c->close();
    }
    while (c->open) {
        bool completed_frame = false;
        for (;;) {
            const auto next =
                modbus::next_adu(std::span(c->rx).subspan(c->begin, c->end - c->begin));
            if (!next) {
                why = next.error().message;
                c->close();
                break;
            }
            if (!*next) break;  // the rest of the request is still on its way
            const auto adu = **next;
            const auto received = c->last_activity;
            const bool contact = keeps_contact(*c, adu);
            note_request(received, contact);
            ++c->requests;
            const int unit_id = counted_unit(adu);
            auto answered = answer(*c, adu);
            answered_request(contact);
            auto* pending = std::get_if<Write>(&answered);
            Response response;
            if (pending) {
                c->busy = true;
                response = co_await write(*c, std::move(*pending));
                c->busy = false;
            } else {
                response = std::move(std::get<Response>(answered));
            }
            if (response && c->open) {
                boost::system::error_code ec;
                const auto written = write_now(*c, *response, ec);
                if (!ec && written < response->size())
                    ec = co_await send_rest(*c, std::span(*response).subspan(written));
                if (ec && c->open) why = fmt::format("sending a response: {}", ec.message());
                if (ec) c->close();
                if (!ec) count(unit_id, adu, *response, received);
            }
            c->last_activity = Clock::now();
            if (stopping_) {
                if (c->open) why = "the gateway is shutting down";
                c->close();
                break;
            }
            if (!response || !c->open) {
                if (!response && c->open) why = "no response could be built";
                c->close();
                break;
            }
            c->begin += adu.size();
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
        const auto n = co_await read_some(*c, ec);
        if (ec) {
            if (c->partial && c->open) why = "connection ended in the middle of a request";
            break;
        }
        c->end += n;
        c->last_activity = Clock::now();
    }
    log_.debug({.client = c->peer}, "Modbus client {} disconnected: {}", c->peer, why);
}
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif

std::variant<ModbusServer::Response, ModbusServer::Write> ModbusServer::answer(
    Connection& c, std::span<const std::uint8_t> adu) {
    const auto& unit = units_[adu[modbus::mbap_length - 1]];
    const PaddedRequest request(adu);
    if (!unit)
        return built(c, replies_->exception(request, modbus::Exception::gateway_path_unavailable));
    const auto pdu = adu.subspan(modbus::mbap_length);
    if (c.tls && !modbus_security::permits(c.rights, unit->link().config().unit_id, pdu[0])) {
        log_role_refusal(c, unit->link().config().unit_id, pdu[0]);
        return built(c, replies_->exception(request, modbus::Exception::illegal_function));
    }
    // Identification is the unit's, not its devices': it answers with the port down and in
    // read_only mode.
    if (pdu[0] == modbus::encapsulated_interface_transport) {
        const auto identification = modbus::read_device_identification(pdu, unit->identity());
        if (!identification) return built(c, replies_->exception(request, identification.error()));
        return ReplyBuilder::framed(request, *identification);
    }
    auto plan = gateway::plan(unit->link().state(), policy_, pdu);
    if (const auto* exception = std::get_if<modbus::Exception>(&plan))
        return built(c, replies_->exception(request, *exception));
    if (const auto* read = std::get_if<gateway::ReadPlan>(&plan)) {
        auto* image = unit->image(read->diagnostics);
        if (read->diagnostics) store_front(*unit);
        return built(c, replies_->reply(request, image));
    }
    return Write{unit, std::get<gateway::WritePlan>(std::move(plan)), request, origin(c, pdu)};
}

void ModbusServer::log_role_refusal(Connection& c, int unit_id, std::uint8_t function) {
    if (std::exchange(c.refusal_logged, true)) return;
    const auto& grants = c.rights.grants;
    log_.warn({.unit = unit_id, .client = c.peer},
              "Modbus/TCP Security client {}: FC {:02} to unit {} refused (exception 01): {} "
              "(logged once per connection)",
              c.peer, function, unit_id,
              !grants ? c.rights.why
              : !grants->units.test(static_cast<std::size_t>(unit_id))
                  ? fmt::format("role {} is not for unit {}", c.rights.role, unit_id)
                  : fmt::format("role {} may only read", c.rights.role));
}

void ModbusServer::count(int unit_id, std::span<const std::uint8_t> adu,
                         std::span<const std::uint8_t> response, Clock::time_point received) {
    const auto pdu = response.subspan(modbus::mbap_length);
    stats_.responses.count(unit_id, adu[modbus::mbap_length], pdu);
    stats_.request_duration.observe(std::chrono::duration<double>(Clock::now() - received).count());
}

WriteOrigin ModbusServer::origin(const Connection& c, std::span<const std::uint8_t> pdu) {
    WriteOrigin origin{.client = c.peer, .asked = c.last_activity};
    const auto request = modbus::parse_request(pdu);
    if (!request) return origin;  // planned as a write, so it parses
    origin.function = std::to_string(static_cast<int>(request->function));
    origin.address = std::to_string(request->address);
    origin.value = modbus::written_values(*request);
    origin.request = fmt::format("FC {:0>2} address {} values {}", origin.function, origin.address,
                                 origin.value);
    return origin;
}

asio::awaitable<ModbusServer::Response> ModbusServer::write(Connection& c, Write write) {
    // FC 23 reads these once its write is done.
    const auto read_address = write.plan.read_address;
    const auto read_quantity = write.plan.read_quantity;
    const auto result =
        co_await write.unit->link().write(std::move(write.plan), std::move(write.origin));
    if (!c.open) co_return std::nullopt;
    if (const auto failed = exception_of(result))
        co_return built(c, replies_->exception(write.request, *failed));
    if (read_quantity == 0) co_return built(c, replies_->reply(write.request, scratch_.get()));
    const auto plan =
        gateway::read_back(write.unit->link().state(), policy_, read_address, read_quantity);
    if (const auto* exception = std::get_if<modbus::Exception>(&plan))
        co_return built(c, replies_->exception(write.request, *exception));
    co_return built(c, ReplyBuilder::read_back(write.request, read_address, read_quantity,
                                               *write.unit->image(false)));
}

ModbusServer::Response ModbusServer::built(const Connection& c, Result<Bytes> response) {
    if (response) return std::move(*response);
    log_.error({.client = c.peer}, "Modbus client {}: {}", c.peer, response.error().message);
    return std::nullopt;
}

}  // namespace ioport::daemon
