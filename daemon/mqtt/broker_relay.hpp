// The path to an MQTT 3.1.1 broker, with a bound on what the broker can make the daemon hold.
//
// libmosquitto reads a packet whole, whatever its remaining length says (up to 256 MB), and
// MQTT 3.1.1 cannot ask a broker for less (MQTT 5's Maximum Packet Size). So to such a broker
// libmosquitto does not connect itself: it connects, without TLS, to this relay on loopback,
// and the relay connects to the broker (TLS and its checks included) and passes the bytes both
// ways, the broker's through mqtt::InboundLimit: a PUBLISH beyond the limit is read in passing,
// counted through `Refused`, and never reaches libmosquitto (gateway.md §7.5).
//
// The loopback port takes one connection, libmosquitto's: the relay is told its address
// (expect()) and closes any other, so no other process on the box can borrow the daemon's
// session with the broker. One relay per connection attempt; close() ends it.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <boost/asio/ssl.hpp>

#include "config/gateway_config.hpp"
#include "link/asio.hpp"
#include "protocol/mqtt_inbound.hpp"

namespace ioport::daemon {

class BrokerRelay : public std::enable_shared_from_this<BrokerRelay> {
  public:
    struct Settings {
        config::BrokerAddress broker;
        // With broker.tls: the context that verifies it (MqttClient makes it from ca_file).
        std::shared_ptr<asio::ssl::context> tls;
        std::size_t limit = 0;  // the largest packet from the broker passed on
        // For the TCP connection and the TLS handshake together: past it, the attempt fails.
        std::chrono::milliseconds connect_timeout{10'000};
    };
    using Refused = std::function<void(const mqtt::RefusedPublish&)>;

    // Listens on 127.0.0.1 (a port of the kernel's choosing) and starts connecting to the
    // broker. Fails only when it cannot listen.
    static Result<std::shared_ptr<BrokerRelay>> open(const asio::any_io_executor& executor,
                                                     Settings settings, Refused refused);
    BrokerRelay(const BrokerRelay&) = delete;
    BrokerRelay& operator=(const BrokerRelay&) = delete;

    std::uint16_t port() const { return port_; }
    // The address libmosquitto's socket connects from: the one connection taken.
    void expect(const asio::ip::tcp::endpoint& client) { expected_ = client; }
    // At once; the connection with the broker is cut, not ended (MqttClient lets a relay end by
    // itself when libmosquitto closes its socket).
    void close();
    // The broker's side was up (TCP, and TLS where it is TLS): what libmosquitto wrote went on.
    bool reached() const { return connected_; }
    // Why the path to the broker ended, or why it is not there yet, for the log; empty when it
    // was there and did not end on the broker's side (libmosquitto then knows why).
    std::string failure() const;

  private:
    BrokerRelay(const asio::any_io_executor& executor, Settings settings, Refused refused);
    std::string broker() const { return config::to_string(settings_.broker); }
    void accept();
    void connect();
    void handshake();
    void ready_broker();  // connected, TLS done
    void ready();         // both sides there: the bytes flow
    void upstream();
    void downstream();
    void end(std::string why);
    // `operation` on the broker's stream: the TLS one, or the TCP socket beneath it.
    template <class Operation>
    void on_broker(Operation&& operation) {
        if (settings_.broker.tls)
            operation(broker_);
        else
            operation(broker_.next_layer());
    }
    void local_ended();
    std::string not_yet() const;  // what the connection to the broker still waits for

    Settings settings_;
    Refused refused_;
    asio::ip::tcp::acceptor acceptor_;
    asio::ip::tcp::socket local_;
    asio::ip::tcp::resolver resolver_;
    asio::ssl::stream<asio::ip::tcp::socket> broker_;  // its TLS layer used with broker.tls
    asio::steady_timer deadline_;
    std::optional<asio::ip::tcp::endpoint> expected_;
    std::uint16_t port_ = 0;
    bool accepted_ = false;
    bool tcp_connected_ = false;
    bool connected_ = false;    // and TLS done
    bool local_ended_ = false;  // libmosquitto closed its end
    bool closed_ = false;
    std::string failure_;
    mqtt::InboundLimit limit_;
    std::vector<std::uint8_t> up_;      // read from libmosquitto, being written to the broker
    std::vector<std::uint8_t> down_;    // read from the broker
    std::vector<std::uint8_t> passed_;  // of it, what libmosquitto may read
    std::vector<mqtt::RefusedPublish> refused_now_;
};

// A TLS client context as libmosquitto's for a broker: TLS 1.2 at least, the broker's
// certificate verified against `ca_file`, or the system's CAs when it is empty. Fails, naming
// the file, when it cannot be loaded.
Result<std::shared_ptr<asio::ssl::context>> broker_tls_context(const std::string& ca_file);

}  // namespace ioport::daemon
