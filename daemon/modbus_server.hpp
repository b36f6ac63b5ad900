// The Modbus TCP front: accepts clients, frames requests by their MBAP header, decides each one
// with the pure gateway map and lets libmodbus build the response from the unit's image.
//
// Per connection: one request at a time, in order, so a write's response can wait for the
// device's acknowledgement while every other connection goes on being served. Reads never wait
// on a serial line. libmodbus is only ever given complete, validated requests in a zero-padded
// buffer (modbus_reply / modbus_reply_exception) and never selects or receives: all socket
// reads and timeouts are Asio's.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <modbus/modbus.h>

#include "config/gateway_config.hpp"
#include "daemon/link_scheduler.hpp"
#include "link/asio.hpp"

namespace ioport::daemon {

// A request must be complete within this time of its first byte (gateway.md §3.5).
inline constexpr std::chrono::microseconds frame_timeout = 1s;

class ModbusServer {
  public:
    // `units`: the links in configuration order; each serves its unit id (and 0 and 255 too when
    // there is exactly one).
    ModbusServer(const asio::any_io_executor& executor, config::ModbusSettings settings,
                 const std::vector<LinkScheduler*>& units);
    ModbusServer(const ModbusServer&) = delete;
    ModbusServer& operator=(const ModbusServer&) = delete;
    ~ModbusServer();

    // Binds and listens; fails when the address is in use or not permitted.
    Result<> start();
    // Stops accepting and closes every connection.
    void stop();

    std::size_t connections() const { return connections_.size(); }
    asio::ip::tcp::endpoint local_endpoint() const;

  private:
    struct Connection;
    using ConnectionPtr = std::shared_ptr<Connection>;

    asio::awaitable<void> accept_loop();
    asio::awaitable<void> serve(ConnectionPtr connection);
    asio::awaitable<void> watch(ConnectionPtr connection);
    asio::awaitable<bool> handle(Connection& connection, std::span<const std::uint8_t> adu);
    std::optional<std::string> refusal(const asio::ip::tcp::endpoint& peer) const;
    void log_refusal(const asio::ip::address& address, const std::string& why);

    config::ModbusSettings settings_;
    gateway::Policy policy_;
    std::array<LinkScheduler*, 256> units_{};
    asio::ip::tcp::acceptor acceptor_;
    asio::steady_timer accept_retry_;
    std::unordered_set<Connection*> connections_;
    std::unordered_map<std::string, Clock::time_point> refused_logged_;
    modbus_mapping_t* scratch_;  // write responses are built here, never in an image
    bool stopping_ = false;
};

}  // namespace ioport::daemon
