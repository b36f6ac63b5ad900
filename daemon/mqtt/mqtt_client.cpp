#include "daemon/mqtt/mqtt_client.hpp"

#include "daemon/mqtt/mqtt_error.hpp"

#include <mosquitto.h>
#include <mqtt_protocol.h>

#include <fmt/format.h>

namespace ioport::daemon {
namespace {

// CONNECT's Maximum Packet Size (MQTT 5, 3.1.2.11.4), and its Session Expiry Interval 0
// (3.1.2.11.2; what an absent one means too, said outright as Sparkplug 3.0 asks of an edge node:
// tck-id-principles-persistence-clean-session-50). libmosquitto 2.0 takes CONNECT properties
// only in mosquitto_connect_bind_v5(), which connects blocking; it keeps them for every later
// connect, the asynchronous ones too, and keeps them before it looks at the host. So they are
// given by a call without a host, which connects nowhere (MOSQ_ERR_INVAL, as meant). The
// huge-PUBLISH tests (tests/mqtt_json, tests/sparkplug) fail if a libmosquitto stops sending
// them so.
Result<> announce_maximum_packet_size(mosquitto* client, std::uint32_t bytes) {
    mosquitto_property* properties = nullptr;
    int rc = mosquitto_property_add_int32(&properties, MQTT_PROP_MAXIMUM_PACKET_SIZE, bytes);
    if (rc == MOSQ_ERR_SUCCESS)
        rc = mosquitto_property_add_int32(&properties, MQTT_PROP_SESSION_EXPIRY_INTERVAL, 0);
    if (rc == MOSQ_ERR_SUCCESS) {
        rc = mosquitto_connect_bind_v5(client, nullptr, 0, 0, nullptr, properties);
        if (rc == MOSQ_ERR_INVAL) rc = MOSQ_ERR_SUCCESS;
    }
    mosquitto_property_free_all(&properties);
    if (rc != MOSQ_ERR_SUCCESS)
        return fail(Errc::io_error,
                    fmt::format("cannot set the Maximum Packet Size: {}", mosquitto_error(rc)));
    return {};
}

}  // namespace

Result<std::shared_ptr<MqttClient>> MqttClient::create(const asio::any_io_executor& executor,
                                                       const config::MqttSettings& settings,
                                                       Protocol protocol, std::string section,
                                                       Log& log, Handlers handlers) {
    std::shared_ptr<MqttClient> client(
        new MqttClient(executor, settings, protocol, std::move(section), log, std::move(handlers)));
    if (auto configured = client->configure(); !configured) return Unexpected(configured.error());
    return client;
}

MqttClient::MqttClient(const asio::any_io_executor& executor, const config::MqttSettings& settings,
                       Protocol protocol, std::string section, Log& log, Handlers handlers)
    : executor_(executor),
      settings_(settings),
      protocol_(protocol),
      section_(std::move(section)),
      log_(log),
      handlers_(std::move(handlers)),
      socket_(executor),
      misc_(executor),
      reconnect_(executor),
      stop_deadline_(executor),
      resolver_(executor),
      last_errors_(settings_.brokers.size()),
      mqtt311_only_(settings_.brokers.size(), false) {
    mosquitto_lib_init();  // counted: each client pairs it with its cleanup
}

MqttClient::~MqttClient() {
    if (relay_) relay_->close();
    forget_socket();
    if (client_ != nullptr) mosquitto_destroy(client_);
    mosquitto_lib_cleanup();
}

std::string MqttClient::broker() const {
    return config::to_string(current());
}

// Each broker once at the start, so that a CA file libmosquitto cannot load is an error now,
// not a reconnect loop later; then the first one, which start() connects to.
Result<> MqttClient::configure() {
    // A clean session, as Sparkplug 3.0 requires of an edge node (§7.1).
    client_ = mosquitto_new(settings_.client_id.c_str(), true, this);
    if (client_ == nullptr)
        return fail(Errc::io_error, fmt::format("{}: cannot make an MQTT client: {}", section_,
                                                std::generic_category().message(errno)));
    for (std::size_t i = settings_.brokers.size(); i-- > 0;) {
        current_ = i;
        if (auto configured = configure_for(current()); !configured) return configured;
    }
    return {};
}

// libmosquitto's client as `broker` needs it: TLS or not is a setting of the client, so the
// client is made afresh (mosquitto_reinitialise) for each broker it connects to.
Result<> MqttClient::configure_for(const config::BrokerAddress& broker) {
    if (const int rc = mosquitto_reinitialise(client_, settings_.client_id.c_str(), true, this);
        rc != MOSQ_ERR_SUCCESS)
        return fail(Errc::io_error, fmt::format("{}: cannot make an MQTT client: {}", section_,
                                                mosquitto_error(rc)));
    mosquitto_int_option(client_, MOSQ_OPT_PROTOCOL_VERSION,
                         mqtt5() ? MQTT_PROTOCOL_V5 : MQTT_PROTOCOL_V311);
    if (mqtt5())
        if (auto announced = announce_maximum_packet_size(client_, protocol_.maximum_packet_size);
            !announced)
            return fail(Errc::io_error, fmt::format("{}: {}", section_, announced.error().message));
    mosquitto_int_option(client_, MOSQ_OPT_TCP_NODELAY, 1);
    mosquitto_connect_callback_set(client_, &MqttClient::on_connect);
    mosquitto_disconnect_callback_set(client_, &MqttClient::on_disconnect);
    mosquitto_publish_callback_set(client_, &MqttClient::on_publish);
    mosquitto_message_callback_set(client_, &MqttClient::on_message);
    mosquitto_subscribe_callback_set(client_, &MqttClient::on_subscribe);
    if (!settings_.username.empty() || !settings_.password.empty()) {
        const int rc = mosquitto_username_pw_set(
            client_, settings_.username.empty() ? nullptr : settings_.username.c_str(),
            settings_.password.empty() ? nullptr : settings_.password.c_str());
        if (rc != MOSQ_ERR_SUCCESS)
            return fail(Errc::invalid_argument,
                        fmt::format("{}.username: {}", section_, mosquitto_error(rc)));
    }
    relay_tls_.reset();
    if (broker.tls && !mqtt5()) {
        // The relay speaks TLS to the broker; libmosquitto speaks plain MQTT to the relay.
        auto context = broker_tls_context(settings_.ca_file);
        if (!context)
            return fail(Errc::invalid_argument,
                        fmt::format("{}.ca_file: {}", section_, context.error().message));
        relay_tls_ = *std::move(context);
    } else if (broker.tls) {
        // Without ca_file, the system's CAs: a broker with a public certificate.
        const int rc = mosquitto_tls_set(
            client_, settings_.ca_file.empty() ? nullptr : settings_.ca_file.c_str(),
            settings_.ca_file.empty() ? "/etc/ssl/certs" : nullptr, nullptr, nullptr, nullptr);
        if (rc != MOSQ_ERR_SUCCESS)
            return fail(Errc::invalid_argument,
                        fmt::format("{}.ca_file: {}: {}", section_, settings_.ca_file,
                                    mosquitto_error(rc)));
        mosquitto_tls_opts_set(client_, 1, "tlsv1.2", nullptr);  // verify the broker, TLS >= 1.2
    }
    return {};
}

Result<> MqttClient::set_will(std::string_view topic, std::span<const std::uint8_t> payload,
                              int qos, bool retain) {
    const int rc =
        mosquitto_will_set(client_, std::string(topic).c_str(), static_cast<int>(payload.size()),
                           payload.data(), qos, retain);
    if (rc != MOSQ_ERR_SUCCESS)
        return fail(Errc::invalid_argument,
                    fmt::format("the will on {}: {}", printable(topic), mosquitto_error(rc)));
    return {};
}

void MqttClient::start() {
    started_ = true;
    tick();
    resolve_then_connect();
}

// libmosquitto looks the host name up itself, with getaddrinfo(), which blocks. It is asked
// only once Asio's resolver (which never blocks this thread) found the name, so that a DNS that
// is down or slow is waited for off the loop; the second lookup then normally comes from the
// same resolver's answer. An IP literal needs no lookup at all.
void MqttClient::resolve_then_connect() {
    attempt_ended_ = false;
    connack_ = false;
    written_ = false;
    const auto& broker = current();
    if (broker.ip_literal() || !mqtt5()) {  // MQTT 3.1.1: the relay resolves the name, with Asio
        connect();
        return;
    }
    resolver_.async_resolve(
        broker.host, std::to_string(broker.port),
        [self = shared_from_this()](const boost::system::error_code& error, const auto&) {
            if (self->stopping_ || error == asio::error::operation_aborted) return;
            if (error) {
                self->lost(
                    fmt::format("cannot resolve {}: {}", self->current().host, error.message()));
                return;
            }
            self->connect();
        });
}

void MqttClient::connect() {
    const auto& broker = current();
    if (auto configured = configure_for(broker); !configured) {
        lost(configured.error().message);
        return;
    }
    if (handlers_.connecting) handlers_.connecting();
    const auto keepalive = std::chrono::duration_cast<std::chrono::seconds>(settings_.keepalive);
    std::string host = broker.host;
    int port = broker.port;
    if (!mqtt5()) {
        if (auto opened = open_relay(); !opened) {
            lost(opened.error().message);
            return;
        }
        host = "127.0.0.1";
        port = relay_->port();
    }
    const int rc =
        mosquitto_connect_async(client_, host.c_str(), port, static_cast<int>(keepalive.count()));
    if (rc != MOSQ_ERR_SUCCESS) {
        lost(fmt::format("cannot connect to {}: {}", config::to_string(broker),
                         mosquitto_error(rc)));
        return;
    }
    // A connection that completed at once (loopback) had its CONNECT written within the call.
    written_ = !mosquitto_want_write(client_);
    if (relay_) {
        // The relay takes the connection from this address only.
        asio::ip::tcp::endpoint from;
        socklen_t length = static_cast<socklen_t>(from.capacity());
        if (getsockname(mosquitto_socket(client_), from.data(), &length) == 0) {
            from.resize(length);
            relay_->expect(from);
        }
    }
    watch();
}

bool MqttClient::connect_sent() const {
    if (connack_) return true;
    // Through the relay, libmosquitto's writes reach the relay at once: the broker had the
    // CONNECT only if the relay reached it.
    if (relay_) return relay_->reached();
    return written_;
}

Result<> MqttClient::open_relay() {
    std::weak_ptr<MqttClient> weak = shared_from_this();
    auto relay = BrokerRelay::open(
        executor_,
        {.broker = current(),
         .tls = relay_tls_,
         .limit = protocol_.maximum_packet_size,
         .connect_timeout =
             std::chrono::duration_cast<std::chrono::milliseconds>(settings_.keepalive)},
        [weak](const mqtt::RefusedPublish& refused) {
            if (auto self = weak.lock()) self->too_large(refused);
        });
    if (!relay) return Unexpected(relay.error());
    relay_ = *std::move(relay);
    return {};
}

// libmosquitto's socket is closed or about to be (lost(), finish_stop(), a new connect): the
// relay then passes on what libmosquitto wrote last and ends by itself.
void MqttClient::forget_relay() {
    relay_.reset();
}

void MqttClient::too_large(const mqtt::RefusedPublish& refused) {
    if (handlers_.too_large) handlers_.too_large(refused.topic, refused.packet_bytes);
}

void MqttClient::forget_socket() {
    if (!socket_.is_open()) return;
    // libmosquitto owns the descriptor and closes it itself: Asio only stops watching it.
    boost::system::error_code ignored;
    socket_.cancel(ignored);
    (void)socket_.release();
}

void MqttClient::watch() {
    const int fd = mosquitto_socket(client_);
    if (socket_.is_open() && socket_.native_handle() != fd) forget_socket();
    if (fd < 0) return;
    if (!socket_.is_open()) {
        boost::system::error_code ec;
        socket_.assign(fd, ec);
        if (ec) {
            log_.error({}, "{}: cannot watch the broker's socket: {}", section_, ec.message());
            return;
        }
    }
    if (!reading_) {
        reading_ = true;
        socket_.async_wait(asio::posix::stream_descriptor::wait_read,
                           [self = shared_from_this()](const boost::system::error_code& ec) {
                               self->reading_ = false;
                               if (ec) {
                                   if (!self->stopping_ || self->stopped_) self->watch();
                                   return;
                               }
                               self->after_io(mosquitto_loop_read(self->client_, 1), "reading");
                           });
    }
    if (!writing_ && mosquitto_want_write(client_)) {
        writing_ = true;
        socket_.async_wait(asio::posix::stream_descriptor::wait_write,
                           [self = shared_from_this()](const boost::system::error_code& ec) {
                               self->writing_ = false;
                               if (ec) {
                                   if (!self->stopping_ || self->stopped_) self->watch();
                                   return;
                               }
                               const int rc = mosquitto_loop_write(self->client_, 16);
                               // The first write of a connection is its CONNECT; it fails when
                               // the TCP connection did.
                               if (rc == MOSQ_ERR_SUCCESS) self->written_ = true;
                               self->after_io(rc, "writing");
                           });
    }
}

void MqttClient::after_io(int rc, std::string_view during) {
    // A lost connection was reported through on_disconnect already; other errors are said here.
    if (rc != MOSQ_ERR_SUCCESS && rc != MOSQ_ERR_CONN_LOST && rc != MOSQ_ERR_NO_CONN &&
        mosquitto_socket(client_) >= 0)
        log_.debug({}, "{}: {} {}: {}", section_, during, broker(), mosquitto_error(rc));
    if (stopped_ && !mosquitto_want_write(client_)) {
        finish_stop();
        return;
    }
    watch();
}

void MqttClient::tick() {
    misc_.expires_after(std::chrono::seconds(1));
    misc_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
        if (ec || !self->started_) return;
        // Keepalive: a PINGREQ when due, and a broker that stopped answering is found out.
        mosquitto_loop_misc(self->client_);
        self->watch();
        self->tick();
    });
}

void MqttClient::lost(const std::string& why, bool same_broker) {
    // Once per attempt: libmosquitto may report one end twice (a refused CONNACK, then the
    // close; a DISCONNECT written, then the socket's end), which would skip a broker.
    if (std::exchange(attempt_ended_, true) && !stopping_) return;
    const bool was_connected = connected_;
    connected_ = false;
    // A connection that lasted, or whose session the broker took, starts the back-off again;
    // one the broker ended at once does not (steady_connection).
    if (was_connected &&
        (established_ || std::chrono::steady_clock::now() - connected_at_ >= steady_connection))
        reconnect_delay_ = first_reconnect_delay;
    queued_.clear();
    queued_bytes_ = 0;
    forget_socket();
    if (stopping_) {
        finish_stop();
        return;
    }
    // The relay still there: the handler may ask connect_sent().
    if (handlers_.disconnected) handlers_.disconnected(why);
    forget_relay();
    if (same_broker) {
        reconnect_.expires_after(std::chrono::seconds(0));
        reconnect_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
            if (!ec && !self->stopping_) self->resolve_then_connect();
        });
        return;
    }
    // Once per distinct reason of each broker while it lasts: brokers away for hours must not
    // flood the log.
    auto& last_error = last_errors_[current_];
    if (was_connected || why != last_error)
        log_.warn({}, "{}: {}; reconnecting within {} s", section_, why, reconnect_delay_.count());
    last_error = why;
    // Several brokers: the next one in the list is tried (gateway.md §6.2).
    current_ = (current_ + 1) % settings_.brokers.size();
    schedule_reconnect();
}

void MqttClient::walk() {
    if (!connected_ || stopping_) return;
    reconnect_delay_ = first_reconnect_delay;
    // DISCONNECT: the caller has said NDEATH itself, and the will goes as Protocol::disconnect
    // says. on_disconnect then takes it from there, as for any lost connection, on to the next
    // broker.
    disconnect();
    watch();
}

int MqttClient::disconnect() {
    switch (protocol_.disconnect) {
        case Disconnect::with_will:
            if (mqtt5())
                return mosquitto_disconnect_v5(client_, MQTT_RC_DISCONNECT_WITH_WILL_MSG, nullptr);
            return mosquitto_disconnect(client_);  // 3.1.1 has no such DISCONNECT
        case Disconnect::discard_will:
            return mosquitto_disconnect(client_);
    }
    return mosquitto_disconnect(client_);
}

void MqttClient::schedule_reconnect() {
    reconnect_.expires_after(reconnect_delay_);
    reconnect_delay_ = std::min(2 * reconnect_delay_, max_reconnect_delay);
    reconnect_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
        if (ec || self->stopping_) return;
        self->resolve_then_connect();
    });
}

bool MqttClient::publish(std::string_view topic, std::span<const std::uint8_t> payload, int qos,
                         bool retain, Bound bound) {
    const bool full = queued_bytes_ + payload.size() > max_queued_bytes;
    if (!connected_ || (full && bound == Bound::queue)) {
        ++dropped_;
        return false;
    }
    int mid = 0;
    const int rc = mosquitto_publish(client_, &mid, std::string(topic).c_str(),
                                     static_cast<int>(payload.size()), payload.data(), qos, retain);
    if (rc != MOSQ_ERR_SUCCESS) {
        ++dropped_;
        return false;
    }
    ++published_;
    if (payload.size() > largest_bytes_) {
        largest_bytes_ = payload.size();
        largest_topic_ = topic;
    }
    // on_publish may have run within mosquitto_publish (written at once, QoS 0): then the id is
    // not queued any more.
    if (!written_now_) {
        queued_[mid] = payload.size();
        queued_bytes_ += payload.size();
    }
    written_now_ = false;
    watch();
    return true;
}

Result<int> MqttClient::subscribe(std::string_view pattern, int qos) {
    int mid = 0;
    const int rc = mosquitto_subscribe(client_, &mid, std::string(pattern).c_str(), qos);
    watch();
    if (rc != MOSQ_ERR_SUCCESS)
        return fail(Errc::io_error,
                    fmt::format("subscribing to {}: {}", printable(pattern), mosquitto_error(rc)));
    return mid;
}

void MqttClient::stop(std::chrono::milliseconds deadline, std::function<void()> done) {
    stopping_ = true;
    started_ = false;
    // Non-empty while the stop is under way: the watchers go on flushing until it is called.
    stopped_ = done ? std::move(done) : [] {};
    misc_.cancel();
    reconnect_.cancel();
    resolver_.cancel();
    if (!connected_) {
        finish_stop();
        return;
    }
    // The deadline is set before DISCONNECT: libmosquitto writes it at once when the socket
    // takes it and then reports the end (on_disconnect, finish_stop) from within
    // mosquitto_disconnect(). A timer armed after that would outlive the client and keep the
    // daemon's loop, and so its exit, waiting for the whole deadline.
    stop_deadline_.expires_after(deadline);
    stop_deadline_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
        if (!ec) self->finish_stop();
    });
    // DISCONNECT after what is queued: a clean end, whose will goes as Protocol::disconnect says.
    disconnect();
    if (!stopped_) return;  // finished already
    watch();
}

void MqttClient::finish_stop() {
    stop_deadline_.cancel();
    connected_ = false;
    forget_socket();
    forget_relay();
    if (auto done = std::exchange(stopped_, nullptr)) done();
}

void MqttClient::on_connect(mosquitto* /*client*/, void* self, int rc) {
    auto& me = *static_cast<MqttClient*>(self);
    me.connack_ = true;
    // A 3.1.1 broker's answer to MQTT 5.
    if (rc == MQTT_RC_UNSUPPORTED_PROTOCOL_VERSION && me.mqtt5() && me.fall_back("refused MQTT 5"))
        return;
    if (rc != 0) {
        // CONNACK refused: libmosquitto keeps the socket open; the reconnect replaces it.
        me.lost(
            fmt::format("{} refused the connection: {}", me.broker(),
                        me.mqtt5() ? mosquitto_reason_string(rc) : mosquitto_connack_string(rc)));
        return;
    }
    me.connected_ = true;
    me.connected_at_ = std::chrono::steady_clock::now();
    me.established_ = false;
    me.largest_bytes_ = 0;
    me.largest_topic_.clear();
    me.last_errors_[me.current_].clear();
    me.log_.info({}, "{}: connected to {} as {} (MQTT {})", me.section_, me.broker(),
                 me.settings_.client_id, me.mqtt5() ? "5" : "3.1.1");
    if (me.handlers_.connected) me.handlers_.connected();
}

void MqttClient::on_disconnect(mosquitto* /*client*/, void* self, int rc) {
    auto& me = *static_cast<MqttClient*>(self);
    if (me.stopping_) {
        me.finish_stop();
        return;
    }
    // RabbitMQ 3.10's answer to MQTT 5: the connection closed, no CONNACK. (A refused TCP
    // connection or a failed TLS handshake are other codes.)
    if (rc == MOSQ_ERR_CONN_LOST && !me.connack_ && me.mqtt5() &&
        me.fall_back("closed the connection after an MQTT 5 CONNECT, without a CONNACK"))
        return;
    me.lost(me.disconnect_reason(rc));
}

bool MqttClient::fall_back(std::string_view how) {
    switch (settings_.protocol) {
        case config::MqttProtocol::v5:
            lost(
                fmt::format("{} {}; protocol: \"5\" is set, so no MQTT 3.1.1: set protocol: "
                            "auto",
                            broker(), how));
            return true;
        case config::MqttProtocol::v311:
            return false;  // never asked in 5
        case config::MqttProtocol::automatic:
            break;
    }
    // The same broker again at once, in 3.1.1, until the daemon restarts.
    mqtt311_only_[current_] = true;
    log_.warn({},
              "{}: {} {}, so MQTT 3.1.1 with it from now on; a message larger than {} bytes is "
              "read in passing and refused",
              section_, broker(), how, protocol_.maximum_packet_size);
    lost(fmt::format("{} {}", broker(), how), true);
    return true;
}

// libmosquitto hands on_disconnect either its own error (MOSQ_ERR_*, below 0x80) or, when an
// MQTT 5 broker sent DISCONNECT, that packet's reason code (0x80 and up, MQTT 5 3.14.2.1), which
// mosquitto_strerror() calls "Unknown error.".
std::string MqttClient::disconnect_reason(int rc) const {
    if (relay_)
        if (auto failure = relay_->failure(); !failure.empty()) return failure;
    if (rc == 0) return fmt::format("{} closed the connection", broker());
    if (mqtt5() && rc >= 0x80 && rc <= 0xFF) {
        auto why = fmt::format("{} sent DISCONNECT: {} (reason code 0x{:02X})", broker(),
                               mosquitto_reason_string(rc), rc);
        if (rc == MQTT_RC_SESSION_TAKEN_OVER)
            why += fmt::format("; another client connected as {}: give each its own client_id",
                               settings_.client_id);
        if (rc == MQTT_RC_PACKET_TOO_LARGE && largest_bytes_ > 0)
            why += fmt::format(
                "; the largest message of this session had {} bytes ({}): raise the broker's "
                "limit on a message's size above it (ejabberd: max_payload_size)",
                largest_bytes_, printable(largest_topic_));
        return why;
    }
    return fmt::format("connection to {} lost: {}", broker(), mosquitto_error(rc));
}

void MqttClient::on_publish(mosquitto* /*client*/, void* self, int mid) {
    auto& me = *static_cast<MqttClient*>(self);
    const auto found = me.queued_.find(mid);
    if (found == me.queued_.end()) {
        me.written_now_ = true;  // within mosquitto_publish(): never queued
        return;
    }
    me.queued_bytes_ -= found->second;
    me.queued_.erase(found);
}

void MqttClient::on_subscribe(mosquitto* /*client*/, void* self, int mid, int /*count*/,
                              const int* /*granted*/) {
    auto& me = *static_cast<MqttClient*>(self);
    if (me.handlers_.subscribed) me.handlers_.subscribed(mid);
}

void MqttClient::on_message(mosquitto* /*client*/, void* self, const mosquitto_message* message) {
    auto& me = *static_cast<MqttClient*>(self);
    if (!me.handlers_.message || message->topic == nullptr) return;
    // What stands in for a PUBLISH the relay refused (mqtt::InboundLimit): acknowledged by
    // libmosquitto, reported through too_large already.
    if (message->topic == mqtt::refused_publish_topic) return;
    me.handlers_.message(message->topic,
                         {static_cast<const std::uint8_t*>(message->payload),
                          static_cast<std::size_t>(message->payloadlen)},
                         message->retain);
}

void connection_families(Exposition& out, std::string_view prefix, std::string_view what,
                         const ConnectionCounts& counts) {
    const std::string connected = fmt::format("{}_connected", prefix);
    const std::string published = fmt::format("{}_messages_published_total", prefix);
    const std::string dropped = fmt::format("{}_messages_dropped_total", prefix);
    out.family(connected, "gauge", fmt::format("1 while {} is connected to its broker", what));
    out.sample(connected, {}, counts.connected ? 1 : 0);
    out.family(published, "counter",
               fmt::format("{} messages handed to the broker connection", what));
    out.sample(published, {}, counts.published);
    out.family(dropped, "counter",
               fmt::format("{} messages dropped: not connected, or the send queue full", what));
    out.sample(dropped, {}, counts.dropped);
}

}  // namespace ioport::daemon
