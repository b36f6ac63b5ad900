#include "daemon/base/listener.hpp"

#include <algorithm>

#include <fmt/format.h>

namespace ioport::daemon {

using asio::ip::tcp;

std::string host_port(const tcp::endpoint& endpoint) {
    return config::host_port(endpoint.address().to_string(), endpoint.port());
}

bool allowed(const std::vector<config::Network>& allow, const asio::ip::address& address) {
    return allow.empty() || std::any_of(allow.begin(), allow.end(), [&](const auto& network) {
               return config::contains(network, address);
           });
}

Result<Acceptor> listen_tcp(const asio::any_io_executor& executor, const std::string& host,
                            std::uint16_t port, std::string_view key) {
    boost::system::error_code ec;
    const auto address = asio::ip::make_address(host, ec);
    if (ec)
        return fail(Errc::invalid_argument, fmt::format("{}: {} is not an IP address", key, host));
    const tcp::endpoint endpoint(address, port);
    auto acceptor = std::make_shared<tcp::acceptor>(executor);
    acceptor->open(endpoint.protocol(), ec);
    if (!ec) acceptor->set_option(tcp::acceptor::reuse_address(true), ec);
    // "[::]:502" takes IPv4 clients too, as ::ffff:a.b.c.d.
    if (!ec && address.is_v6()) acceptor->set_option(asio::ip::v6_only(false), ec);
    if (!ec) acceptor->bind(endpoint, ec);
    if (!ec) acceptor->listen(asio::socket_base::max_listen_connections, ec);
    if (ec) {
        const auto hint =
            ec == asio::error::address_in_use
                ? std::string("another program listens there (find it with: ss -ltnp)")
            : ec == asio::error::access_denied
                ? std::string(
                      "ports below 1024 need CAP_NET_BIND_SERVICE (the packaged "
                      "service has it) or use a port such as 1502")
                : fmt::format("check {}", key);
        // The key first: with a Modbus and an HTTP listener, the address alone does not say
        // which line of the configuration to change.
        return fail(Errc::io_error, fmt::format("{}: cannot listen on {}: {}: {}", key,
                                                host_port(endpoint), ec.message(), hint));
    }
    return acceptor;
}

}  // namespace ioport::daemon
