// What the TCP servers (Modbus, HTTP) share: binding a listening socket with an error a person
// can act on, the allow list, and how a peer is written in logs.
#pragma once

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "config/gateway_config.hpp"
#include "link/asio.hpp"
#include "protocol/error.hpp"

namespace ioport::daemon {

using Acceptor = std::shared_ptr<asio::ip::tcp::acceptor>;

// Binds and listens on host:port ("[::]" takes IPv4 clients too). `key` names the setting in
// messages: "modbus.listen".
Result<Acceptor> listen_tcp(const asio::any_io_executor& executor, const std::string& host,
                            std::uint16_t port, std::string_view key);

// Whether a client at `address` may connect: `allow` is empty or has a network with it.
bool allowed(const std::vector<config::Network>& allow, const asio::ip::address& address);

// "10.0.0.5:50123", "[::1]:50123".
std::string host_port(const asio::ip::tcp::endpoint& endpoint);

}  // namespace ioport::daemon
