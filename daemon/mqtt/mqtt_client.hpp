// One MQTT connection on the daemon's io_context: libmosquitto frames packets and keeps the
// session; Asio watches its socket (mosquitto_socket) and calls mosquitto_loop_read/write when
// it is ready, and mosquitto_loop_misc once a second for keepalive. No thread of libmosquitto's
// (no loop_start) and nothing that waits: a broker that is down, slow or refusing costs the
// loop a system call now and then, never a wait.
//
// Publication is bounded: at most max_queued_bytes may wait in libmosquitto's queue for the
// socket; a publish beyond that, or while not connected, is dropped and counted, and the caller
// decides what that means (the edge node rebirths when the connection is back).
//
// What a broker sends would be read whole by libmosquitto before anyone sees it, whatever its
// size (a 250 MB PUBLISH took the daemon past MemoryMax=): once it has a packet's remaining
// length it allocates that much and reads on, with no limit of its own for a client
// (libmosquitto 2.0, packet__read). So nothing larger than Protocol::maximum_packet_size reaches
// it: with MQTT 5 the client announces that Maximum Packet Size in CONNECT, and the broker must
// send it nothing larger (MQTT 5 3.1.2-24); with MQTT 3.1.1, which cannot ask, libmosquitto
// talks to the broker through a BrokerRelay, which reads a larger PUBLISH in passing and hands
// only its topic and size to Handlers::too_large. `protocol: auto` (the default) speaks 5, and
// 3.1.1 to a broker that refuses 5 or closes the connection without a CONNACK; it says so,
// and keeps to 3.1.1 with that broker until the daemon restarts.
//
// Owned through a shared_ptr: its completions keep it alive.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/base/log.hpp"
#include "daemon/mqtt/broker_relay.hpp"
#include "link/asio.hpp"
#include "protocol/exposition.hpp"

struct mosquitto;
struct mosquitto_message;

namespace ioport::daemon {

inline constexpr std::size_t max_queued_bytes = std::size_t{4} << 20;
inline constexpr std::chrono::seconds first_reconnect_delay{1};
inline constexpr std::chrono::seconds max_reconnect_delay{30};
// A connection lost after lasting this long since its CONNACK, or after its output said the
// broker took what the session begins with (session_established), begins the back-off again
// at first_reconnect_delay; one lost sooner goes on doubling it. A broker that ends every session
// at once (a birth over its size limit, a subscription queue it cannot declare) was otherwise
// tried again every second for as long as that lasted, each session a new bdSeq and births.
inline constexpr std::chrono::seconds steady_connection{10};

class MqttClient : public std::enable_shared_from_this<MqttClient> {
  public:
    struct Handlers {
        // Right before each CONNECT: the moment to set the will of the session it begins.
        std::function<void()> connecting;
        // The broker accepted the CONNECT.
        std::function<void()> connected;
        // The connection is gone, or the CONNECT was refused; a reconnect is scheduled.
        std::function<void(const std::string& why)> disconnected;
        // `retained`: the broker kept it from before (a state, not news).
        std::function<void(std::string_view topic, std::span<const std::uint8_t> payload,
                           bool retained)>
            message;
        // SUBACK of subscribe()'s message id: the broker has read everything sent before the
        // SUBSCRIBE on this connection (MQTT keeps a connection's packets in order).
        std::function<void(int mid)> subscribed;
        // A PUBLISH larger than Protocol::maximum_packet_size, refused unread (MQTT 3.1.1
        // only: to an MQTT 5 client the broker does not send one). `topic` as the broker sent
        // it, not checked.
        std::function<void(std::string_view topic, std::uint64_t bytes)> too_large;
    };

    // What this client's own DISCONNECT (stop(), walk()) asks of the broker. MQTT 3.1.1 has
    // one DISCONNECT, which discards the will; MQTT 5 may ask for the will (reason code 0x04),
    // and Sparkplug 3.0 requires that of an edge node (NDEATH published, then the will too).
    enum class Disconnect { discard_will, with_will };

    // The largest packet this client takes; in MQTT 5 with Clean Start and a Session Expiry
    // Interval of 0 (the session ends with the connection, as 3.1.1's Clean Session does).
    // Which MQTT: the settings' `protocol`.
    struct Protocol {
        std::uint32_t maximum_packet_size = 0;
        Disconnect disconnect = Disconnect::discard_will;
    };

    // Fails when libmosquitto cannot make the client or take the settings (a CA file it
    // cannot load, say). `section`: the configuration's ("mqtt", "mqtt_json"), which begins its
    // log lines and errors.
    static Result<std::shared_ptr<MqttClient>> create(const asio::any_io_executor& executor,
                                                      const config::MqttSettings& settings,
                                                      Protocol protocol, std::string section,
                                                      Log& log, Handlers handlers);
    ~MqttClient();
    MqttClient(const MqttClient&) = delete;
    MqttClient& operator=(const MqttClient&) = delete;

    // Connects, and reconnects whenever the connection is lost (1 s doubling to 30 s, back to
    // 1 s after a connection that lasted steady_connection); with several brokers, to the
    // next in the list each time.
    void start();
    // The output's word that the broker read what followed the start of this connection's
    // session (with a Sparkplug store: a SUBACK proving live data or forwarded records after the
    // births): losing it later starts the back-off again, as a broker that ends every session
    // at once (at its first birth) does not.
    void session_established() { established_ = true; }
    // Leaves this broker for the next (gateway.md §6.2): DISCONNECT now (Protocol::disconnect
    // says what becomes of the will), the next one in 1 s.
    void walk();
    // Sets the will of the next CONNECT; fails when libmosquitto refuses it (a topic or payload
    // it does not take).
    Result<> set_will(std::string_view topic, std::span<const std::uint8_t> payload, int qos,
                      bool retain);
    // Whether a publish respects the queue's bound; none is for the few bytes of a message that
    // must not be lost to a backlog (NDEATH).
    enum class Bound { queue, none };
    // False, and counted in dropped(), when not connected or the queue is full.
    bool publish(std::string_view topic, std::span<const std::uint8_t> payload, int qos,
                 bool retain, Bound bound = Bound::queue);
    // The SUBSCRIBE's message id (Handlers::subscribed gets it back with the SUBACK); fails when
    // it cannot be queued (not connected, out of memory).
    Result<int> subscribe(std::string_view pattern, int qos);
    // The clean end: what is queued is sent, then DISCONNECT (Protocol::disconnect says whether
    // the broker publishes the will), then `done`; at once when not connected. Not within
    // `deadline`: the socket is closed anyway.
    void stop(std::chrono::milliseconds deadline, std::function<void()> done);

    bool connected() const { return connected_; }
    // Whether the CONNECT of the current (or just ended) attempt went out to a broker: not when
    // the name did not resolve, the TCP connection or the TLS handshake failed. A will set for an
    // attempt that sent none was never seen by any broker (Sparkplug's bdSeq is not spent).
    bool connect_sent() const;
    std::uint64_t dropped() const { return dropped_; }
    std::uint64_t published() const { return published_; }
    std::string broker() const;  // the current one, as a URL

  private:
    MqttClient(const asio::any_io_executor& executor, const config::MqttSettings& settings,
               Protocol protocol, std::string section, Log& log, Handlers handlers);
    // MQTT 5 with the current broker: not set to 3.1.1, and the broker did not refuse 5.
    bool mqtt5() const {
        return settings_.protocol != config::MqttProtocol::v311 && !mqtt311_only_[current_];
    }
    // The current broker refused MQTT 5 (`how`): with `protocol: auto`, 3.1.1 from now on.
    bool fall_back(std::string_view how);
    Result<> open_relay();
    void too_large(const mqtt::RefusedPublish& refused);
    Result<> configure();
    Result<> configure_for(const config::BrokerAddress& broker);
    const config::BrokerAddress& current() const { return settings_.brokers[current_]; }
    void connect();
    void resolve_then_connect();
    void watch();
    void forget_socket();
    // DISCONNECT as Protocol::disconnect says: libmosquitto's return code.
    int disconnect();
    void after_io(int rc, std::string_view during);
    // What on_disconnect's rc means, for the log.
    std::string disconnect_reason(int rc) const;
    // The attempt or the connection ended; the next goes to the next broker, or, with
    // `same_broker`, to this one again at once (a protocol fallback).
    void lost(const std::string& why, bool same_broker = false);
    void forget_relay();
    void schedule_reconnect();
    void tick();
    void finish_stop();

    static void on_connect(mosquitto* client, void* self, int rc);
    static void on_disconnect(mosquitto* client, void* self, int rc);
    static void on_publish(mosquitto* client, void* self, int mid);
    static void on_message(mosquitto* client, void* self, const mosquitto_message* message);
    static void on_subscribe(mosquitto* client, void* self, int mid, int count, const int* granted);

    asio::any_io_executor executor_;
    config::MqttSettings settings_;
    Protocol protocol_;
    std::string section_;
    Log& log_;
    Handlers handlers_;
    mosquitto* client_ = nullptr;
    asio::posix::stream_descriptor socket_;
    asio::steady_timer misc_;
    asio::steady_timer reconnect_;
    asio::steady_timer stop_deadline_;
    asio::ip::tcp::resolver resolver_;
    bool reading_ = false;
    bool writing_ = false;
    bool started_ = false;
    bool connected_ = false;
    bool attempt_ended_ = false;  // lost() ran for the current connection attempt
    bool stopping_ = false;
    std::size_t current_ = 0;  // into settings_.brokers
    std::chrono::seconds reconnect_delay_ = first_reconnect_delay;
    std::function<void()> stopped_;
    std::unordered_map<int, std::size_t> queued_;  // by message id: bytes not yet written
    std::size_t queued_bytes_ = 0;
    bool written_now_ = false;  // on_publish ran within mosquitto_publish()
    std::uint64_t dropped_ = 0;
    std::uint64_t published_ = 0;
    std::vector<std::string> last_errors_;  // by broker: the reason last logged
    std::vector<bool> mqtt311_only_;        // by broker: it refused MQTT 5
    bool connack_ = false;                  // the current connection had its CONNACK
    bool written_ = false;                  // libmosquitto wrote on the current connection
    // The current connection's CONNACK, and the largest message published on it (for a broker
    // that ends it as too large: MQTT 5's DISCONNECT 0x95).
    std::chrono::steady_clock::time_point connected_at_;
    bool established_ = false;  // session_established() on the current connection
    std::size_t largest_bytes_ = 0;
    std::string largest_topic_;
    // MQTT 3.1.1: the path to the current broker, and its TLS context (made at configure_for,
    // so that a CA file that cannot be loaded is found at once).
    std::shared_ptr<BrokerRelay> relay_;
    std::shared_ptr<asio::ssl::context> relay_tls_;
};

// The three families of an MQTT connection on /metrics, `prefix`_connected,
// …_messages_published_total and …_messages_dropped_total; `what` names the connection in their
// help.
struct ConnectionCounts {
    bool connected = false;
    std::uint64_t published = 0;
    std::uint64_t dropped = 0;
};
void connection_families(Exposition& out, std::string_view prefix, std::string_view what,
                         const ConnectionCounts& counts);

}  // namespace ioport::daemon
