// The Modbus TCP front: accepts clients, frames requests by their MBAP header, decides each one
// with the pure gateway map and lets libmodbus build the response from the unit's image.
//
// Per connection: one request at a time, in order, so a write's response can wait for the
// device's acknowledgement while every other connection goes on being served. Reads never wait
// on a serial line. libmodbus is only ever given complete, validated requests in a zero-padded
// buffer (modbus_reply / modbus_reply_exception), builds the response into memory (see
// modbus_reply.hpp) and never touches a client's socket: all socket reads, writes and timeouts
// are Asio's. A response is written whole; a client that does not read its responses is not
// read from either (TCP flow control does the rest) and is closed when it has read nothing for
// `send_timeout` while a response waits.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <variant>
#include <vector>

#include <modbus/modbus.h>

#include "config/gateway_config.hpp"
#include "daemon/base/listener.hpp"
#include "daemon/core/comm_loss.hpp"
#include "daemon/core/histogram.hpp"
#include "daemon/core/link_scheduler.hpp"
#include "daemon/modbus/modbus_reply.hpp"
#include "daemon/modbus/modbus_tls.hpp"
#include "daemon/modbus/modbus_unit.hpp"
#include "link/asio.hpp"
#include "protocol/request_labels.hpp"

namespace ioport::daemon {

// A request must be complete within this time of its first byte (gateway.md §3.5).
inline constexpr std::chrono::microseconds frame_timeout = 1s;
// A TLS client must complete its handshake within this time of connecting: one that opens and
// says nothing, or trickles its handshake, gives its place of tls.max_handshakes back.
inline constexpr std::chrono::microseconds tls_handshake_timeout = 5s;
// A response must make progress into the client's socket within this time. The socket buffers
// hold hundreds of responses, so only a client that stopped reading altogether gets here.
inline constexpr std::chrono::microseconds send_timeout = 5s;

// Upper bounds of ioportd_modbus_request_duration_seconds: reads are answered from memory in
// tens of microseconds, writes wait for a serial transaction of milliseconds, or its retries.
inline constexpr std::array<double, 16> request_duration_bounds{
    0.00005, 0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01,
    0.025,   0.05,   0.1,     0.25,   0.5,   1,      2.5,   5};

// What the server counted since it started, for /metrics: kept across reloads.
struct ModbusStats {
    gateway::RequestCounts responses;  // by unit, function and exception; each unit's traffic
    Histogram request_duration{request_duration_bounds};  // frame received → response sent
    std::uint64_t refused_not_allowed = 0;
    std::uint64_t refused_too_many = 0;       // max_connections, or out of file descriptors
    std::uint64_t refused_tls_handshake = 0;  // no valid client certificate, old TLS, plaintext
    // tls.max_handshakes in progress, or per_address_handshakes of the client's address
    std::uint64_t refused_too_many_handshakes = 0;
};

// A client connected now.
struct ClientView {
    std::string address;  // "10.0.0.5:50123"
    std::chrono::system_clock::time_point since;
    std::uint64_t requests = 0;
    bool tls = false;
    std::string role;  // TLS: the client's role, "" for none
};

// Owned through a shared_ptr: its coroutines keep it alive (see spawn()).
class ModbusServer : public std::enable_shared_from_this<ModbusServer> {
  public:
    // `links`: in configuration order; each serves its unit id (and 0 and 255 too when there is
    // exactly one). `comm_loss`: the gateway's watch (gateway.md §5.3), told of every request
    // that shows a SCADA is there.
    ModbusServer(const asio::any_io_executor& executor, config::ModbusSettings settings,
                 const Links& links, Log& log, EventBus& bus,
                 std::shared_ptr<CommLossWatch> comm_loss);
    ModbusServer(const ModbusServer&) = delete;
    ModbusServer& operator=(const ModbusServer&) = delete;
    ~ModbusServer();

    // Binds and listens (plain Modbus TCP, Modbus/TCP Security, or both); fails when an address
    // is in use or not permitted, or the TLS context cannot be made.
    Result<> start();
    // The orderly end: stops accepting and reading; a connection waiting for a write's outcome
    // is closed once its response is sent, every other one at once.
    void shut_down();
    // The abrupt end: closes every connection now.
    void stop();

    // A reload in two steps, so that nothing changes unless everything can: prepare() binds the
    // new listen addresses if they differ and makes the new TLS context (certificates read anew);
    // apply() takes the new settings and links. Connections are kept, but those the new `allow`
    // refuses; TLS clients keep the role they connected with.
    Result<> prepare(const config::ModbusSettings& next);
    void apply(config::ModbusSettings next, const Links& links);
    // Lets go of what prepare() bound, when the reload goes no further.
    void abandon();

    // Clients connected now, plain or past their TLS handshake: what max_connections bounds.
    std::size_t connections() const { return connections_.size() - handshakes_; }
    // TLS connections still in their handshake (tls.max_handshakes bounds them).
    std::size_t handshakes() const { return handshakes_; }
    // A communication loss is in effect: declared, and no request since (register 1020).
    bool comm_lost() const { return comm_loss_->lost(); }
    // Where the plain and the TLS listener are; a default endpoint for one that is off.
    asio::ip::tcp::endpoint local_endpoint() const;
    asio::ip::tcp::endpoint tls_endpoint() const;
    const config::ModbusSettings& settings() const { return settings_; }
    const ModbusStats& stats() const { return stats_; }
    std::vector<ClientView> clients() const;

  private:
    struct Connection;
    using ConnectionPtr = std::shared_ptr<Connection>;

    enum class Transport { tcp, tls };
    // The listener of a transport: its socket and, for TLS, the context new connections get.
    struct Listener {
        Acceptor acceptor;
        Acceptor next;  // bound by prepare(), taken by apply()
        TlsContext context;
        TlsContext next_context;
    };
    Listener& listener(Transport transport);
    static bool same_address(const config::ModbusSettings& a, const config::ModbusSettings& b,
                             Transport transport);
    Result<Acceptor> listen(const config::ModbusSettings& settings, Transport transport);
    Result<> prepare(const config::ModbusSettings& next, Transport transport);
    void apply(const config::ModbusSettings& next, Transport transport);
    void set_units(const Links& links);
    void accept_on(Transport transport, Acceptor acceptor);
    void close(Listener& listener);
    asio::awaitable<void> accept_loop(Transport transport, Acceptor acceptor);
    void configure(asio::ip::tcp::socket& socket) const;
    asio::awaitable<void> serve(ConnectionPtr connection);
    // The TLS handshake within tls_handshake_timeout, then the client's rights; false when the
    // connection is to be closed.
    asio::awaitable<bool> handshake(Connection& connection);
    asio::awaitable<std::size_t> read_some(Connection& connection, boost::system::error_code& ec);
    std::size_t write_now(Connection& connection, const Bytes& response,
                          boost::system::error_code& ec);
    asio::awaitable<boost::system::error_code> send_rest(Connection& connection,
                                                         std::span<const std::uint8_t> rest);
    void forget(Connection& connection);
    asio::awaitable<void> watch(ConnectionPtr connection);
    void spawn(std::string_view what, std::function<asio::awaitable<void>()> coroutine);
    // A write that must reach the device before its response.
    struct Write {
        std::shared_ptr<ModbusUnit> unit;  // held: a reload may replace the link meanwhile
        gateway::WritePlan plan;
        PaddedRequest request;  // what the response is built from
        WriteOrigin origin;     // taken from the request before the connection's buffer moves on
    };
    // A response, or nullopt when none can be built (libmodbus failed).
    using Response = std::optional<Bytes>;
    // Reads and refusals are answered at once, from the image: no coroutine, no wait.
    std::variant<Response, Write> answer(Connection& connection, std::span<const std::uint8_t> adu);
    // The response once the device acknowledged or failed; nullopt also when the connection
    // closed meanwhile.
    asio::awaitable<Response> write(Connection& connection, Write write);
    // The response libmodbus built, or nullopt, logged, when it failed.
    Response built(const Connection& connection, Result<Bytes> response);
    // Takes the descriptors that settings_.max_connections clients need (see descriptors.hpp).
    void make_room();
    // A request arrived at `at`: 1019's interval, and with `contact` the communication-loss
    // watch.
    void note_request(Clock::time_point at, bool contact);
    void answered_request(bool contact);
    // The request is one that keeps the communication-loss timer from firing.
    bool keeps_contact(const Connection& connection, std::span<const std::uint8_t> adu) const;
    // The unit id whose traffic a request counts in: its link's, or -1 for an unknown unit.
    int counted_unit(std::span<const std::uint8_t> adu) const;
    // A response sent: §5.1's traffic and the metrics.
    void count(int unit_id, std::span<const std::uint8_t> adu,
               std::span<const std::uint8_t> response, Clock::time_point received);
    // A request the client's role does not allow, logged the first time on a connection.
    void log_role_refusal(Connection& connection, int unit_id, std::uint8_t function);
    // Who asked for a write and what, for the link's audit record.
    static WriteOrigin origin(const Connection& connection, std::span<const std::uint8_t> pdu);
    // Registers 1010-1020 of `unit`, as of now.
    void store_front(ModbusUnit& unit) const;
    // Why a client just accepted is closed at once, and the counter of that reason.
    struct Refusal {
        std::uint64_t* counted;
        std::string why;
    };
    std::optional<Refusal> refusal(const asio::ip::tcp::endpoint& peer, Transport transport);
    std::string too_many() const;
    // The handshake budget (gateway.md §5.6): taken at accept, given back when it ends.
    void begin_handshake(Connection& connection);
    void end_handshake(Connection& connection);
    // A reload's client_crl: the TLS clients whose certificate it revokes are closed.
    void close_revoked();
    bool allowed(const asio::ip::address& address) const;
    void log_refusal(const asio::ip::address& address, const std::string& why);

    asio::any_io_executor executor_;
    config::ModbusSettings settings_;
    gateway::Policy policy_;
    Log& log_;
    EventBus& bus_;
    ModbusStats stats_;
    std::array<std::shared_ptr<ModbusUnit>, 256> units_{};
    Listener plain_;
    Listener tls_;
    asio::steady_timer accept_retry_;
    std::unordered_set<Connection*> connections_;
    LogLimiter refusals_;
    std::size_t handshakes_ = 0;
    std::map<asio::ip::address, int> handshakes_by_address_;  // only addresses with some
    Mapping scratch_;  // write responses are built here, never in an image
    std::unique_ptr<ReplyBuilder> replies_;
    std::size_t max_clients_ = 0;  // max_connections, or fewer when descriptors are short
    std::size_t ports_ = 0;
    bool stopping_ = false;
    Clock::time_point last_request_ = Clock::now();  // any request: 1019
    std::chrono::microseconds since_previous_{};
    std::shared_ptr<CommLossWatch> comm_loss_;  // §5.3, the gateway's
};

}  // namespace ioport::daemon
