#include "daemon/mqtt/broker_relay.hpp"

#include <openssl/ssl.h>
#include <openssl/x509_vfy.h>

#include <fmt/format.h>

namespace ioport::daemon {
namespace {

constexpr std::size_t read_bytes = 16 << 10;
// How long the broker has to close its end after libmosquitto closed its own.
constexpr std::chrono::seconds closing_grace{5};

}  // namespace

Result<std::shared_ptr<asio::ssl::context>> broker_tls_context(const std::string& ca_file) {
    auto context = std::make_shared<asio::ssl::context>(asio::ssl::context::tls_client);
    SSL_CTX_set_min_proto_version(context->native_handle(), TLS1_2_VERSION);
    boost::system::error_code ec;
    if (ca_file.empty())
        context->add_verify_path("/etc/ssl/certs", ec);  // a broker with a public certificate
    else
        context->load_verify_file(ca_file, ec);
    if (ec)
        return fail(Errc::invalid_argument,
                    fmt::format("cannot load the CA {}: {}",
                                ca_file.empty() ? "/etc/ssl/certs" : ca_file, ec.message()));
    context->set_verify_mode(asio::ssl::verify_peer);
    return context;
}

Result<std::shared_ptr<BrokerRelay>> BrokerRelay::open(const asio::any_io_executor& executor,
                                                       Settings settings, Refused refused) {
    if (!settings.tls) {
        // A TLS context even for a plain broker, which never uses it: the stream is made with one.
        settings.tls = std::make_shared<asio::ssl::context>(asio::ssl::context::tls_client);
    }
    std::shared_ptr<BrokerRelay> relay(
        new BrokerRelay(executor, std::move(settings), std::move(refused)));
    boost::system::error_code ec;
    const asio::ip::tcp::endpoint loopback(asio::ip::address_v4::loopback(), 0);
    if (relay->acceptor_.open(loopback.protocol(), ec); !ec) relay->acceptor_.bind(loopback, ec);
    if (!ec) relay->acceptor_.listen(1, ec);
    if (!ec) relay->port_ = relay->acceptor_.local_endpoint(ec).port();
    if (ec)
        return fail(Errc::io_error,
                    fmt::format("cannot listen on loopback for the connection to {}: {}",
                                relay->broker(), ec.message()));
    relay->accept();
    relay->connect();
    return relay;
}

BrokerRelay::BrokerRelay(const asio::any_io_executor& executor, Settings settings, Refused refused)
    : settings_(std::move(settings)),
      refused_(std::move(refused)),
      acceptor_(executor),
      local_(executor),
      resolver_(executor),
      broker_(executor, *settings_.tls),
      deadline_(executor),
      limit_(settings_.limit) {}

void BrokerRelay::accept() {
    acceptor_.async_accept([self = shared_from_this()](const boost::system::error_code& ec,
                                                       asio::ip::tcp::socket socket) {
        if (self->closed_) return;
        if (ec) {
            self->end(
                fmt::format("cannot take libmosquitto's connection on loopback: {}", ec.message()));
            return;
        }
        boost::system::error_code peer_error;
        const auto peer = socket.remote_endpoint(peer_error);
        if (peer_error || peer != self->expected_) {
            // Another process on the box: it does not get the daemon's session.
            socket.close(peer_error);
            self->accept();
            return;
        }
        self->local_ = std::move(socket);
        self->local_.set_option(asio::ip::tcp::no_delay(true), peer_error);
        self->accepted_ = true;
        self->acceptor_.close(peer_error);
        if (self->connected_) self->ready();
    });
}

void BrokerRelay::connect() {
    deadline_.expires_after(settings_.connect_timeout);
    deadline_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
        if (ec || self->closed_ || self->connected_) return;
        self->end(self->not_yet());
    });
    const auto& broker = settings_.broker;
    resolver_.async_resolve(
        broker.host, std::to_string(broker.port),
        [self = shared_from_this()](const boost::system::error_code& ec,
                                    const asio::ip::tcp::resolver::results_type& endpoints) {
            if (self->closed_) return;
            if (ec) {
                self->end(fmt::format("cannot resolve {}: {}", self->settings_.broker.host,
                                      ec.message()));
                return;
            }
            asio::async_connect(
                self->broker_.next_layer(), endpoints,
                [self](const boost::system::error_code& error, const asio::ip::tcp::endpoint&) {
                    if (self->closed_) return;
                    if (error) {
                        self->end(fmt::format("cannot connect to {}: {}", self->broker(),
                                              error.message()));
                        return;
                    }
                    self->tcp_connected_ = true;
                    boost::system::error_code ignored;
                    self->broker_.next_layer().set_option(asio::ip::tcp::no_delay(true), ignored);
                    if (self->settings_.broker.tls)
                        self->handshake();
                    else
                        self->ready_broker();
                });
        });
}

// As libmosquitto checks a broker: its certificate chains to the CA and names the host of the
// broker's URL (an IP literal as an IP address); the name is also sent for SNI.
void BrokerRelay::handshake() {
    SSL* ssl = broker_.native_handle();
    const auto& host = settings_.broker.host;
    X509_VERIFY_PARAM* check = SSL_get0_param(ssl);
    if (settings_.broker.ip_literal()) {
        X509_VERIFY_PARAM_set1_ip_asc(check, host.c_str());
    } else {
        SSL_set_tlsext_host_name(ssl, host.c_str());
        X509_VERIFY_PARAM_set1_host(check, host.c_str(), host.size());
    }
    broker_.async_handshake(
        asio::ssl::stream_base::client,
        [self = shared_from_this()](const boost::system::error_code& ec) {
            if (self->closed_) return;
            if (!ec) {
                self->ready_broker();
                return;
            }
            const long verified = SSL_get_verify_result(self->broker_.native_handle());
            if (verified != X509_V_OK) {
                self->end(
                    fmt::format("{}'s certificate is not accepted: {}; ca_file must be the "
                                "CA that signed it, for the name in the URL",
                                self->broker(), X509_verify_cert_error_string(verified)));
                return;
            }
            self->end(fmt::format("TLS with {} failed: {}", self->broker(), ec.message()));
        });
}

void BrokerRelay::ready_broker() {
    connected_ = true;
    deadline_.cancel();
    if (accepted_) ready();
}

void BrokerRelay::ready() {
    upstream();
    downstream();
}

// libmosquitto's bytes to the broker, as they are.
void BrokerRelay::upstream() {
    up_.resize(read_bytes);
    local_.async_read_some(
        asio::buffer(up_),
        [self = shared_from_this()](const boost::system::error_code& ec, std::size_t n) {
            if (self->closed_) return;
            if (ec) {
                self->local_ended();
                return;
            }
            auto written = [self](const boost::system::error_code& error, std::size_t) {
                if (self->closed_) return;
                if (error) {
                    self->end(
                        fmt::format("connection to {} lost: {}", self->broker(), error.message()));
                    return;
                }
                self->upstream();
            };
            self->on_broker([&](auto& stream) {
                asio::async_write(stream, asio::buffer(self->up_.data(), n), written);
            });
        });
}

// The broker's bytes to libmosquitto, through the bound.
void BrokerRelay::downstream() {
    down_.resize(read_bytes);
    auto read = [self = shared_from_this()](const boost::system::error_code& ec, std::size_t n) {
        if (self->closed_) return;
        if (ec) {
            self->end(ec == asio::error::eof || ec == asio::ssl::error::stream_truncated
                          ? fmt::format("{} closed the connection", self->broker())
                          : fmt::format("connection to {} lost: {}", self->broker(), ec.message()));
            return;
        }
        self->passed_.clear();
        self->refused_now_.clear();
        const auto taken =
            self->limit_.take(std::span(self->down_.data(), n), self->passed_, self->refused_now_);
        for (const auto& refused : self->refused_now_)
            self->refused_(refused);
        if (!taken) {
            self->end(fmt::format("{} sent what this client cannot take: {}", self->broker(),
                                  taken.error().message));
            return;
        }
        if (self->passed_.empty() || self->local_ended_) {
            self->downstream();
            return;
        }
        asio::async_write(self->local_, asio::buffer(self->passed_),
                          [self](const boost::system::error_code& error, std::size_t) {
                              if (self->closed_) return;
                              if (error) self->local_ended();
                              self->downstream();
                          });
    };
    on_broker([&](auto& stream) { stream.async_read_some(asio::buffer(down_), std::move(read)); });
}

// libmosquitto closed its end, after its DISCONNECT where it sent one. The broker gets a FIN
// after the last byte, and the relay reads on until the broker closes too: closing at once, with
// the broker's answers unread, would send a reset that can overtake the DISCONNECT, and the
// broker would publish a will that was to be discarded.
void BrokerRelay::local_ended() {
    if (std::exchange(local_ended_, true)) return;
    if (!connected_) {
        close();
        return;
    }
    boost::system::error_code ignored;
    broker_.next_layer().shutdown(asio::ip::tcp::socket::shutdown_send, ignored);
    deadline_.expires_after(closing_grace);
    deadline_.async_wait([self = shared_from_this()](const boost::system::error_code& ec) {
        if (!ec) self->close();
    });
}

std::string BrokerRelay::not_yet() const {
    const auto seconds = std::chrono::duration<double>(settings_.connect_timeout).count();
    return tcp_connected_ ? fmt::format("no TLS handshake with {} within {} s", broker(), seconds)
                          : fmt::format("no connection to {} within {} s", broker(), seconds);
}

std::string BrokerRelay::failure() const {
    if (!failure_.empty() || connected_) return failure_;
    return not_yet();
}

void BrokerRelay::end(std::string why) {
    if (closed_) return;
    failure_ = std::move(why);
    close();
}

void BrokerRelay::close() {
    if (std::exchange(closed_, true)) return;
    boost::system::error_code ignored;
    deadline_.cancel();
    resolver_.cancel();
    acceptor_.close(ignored);
    local_.close(ignored);  // libmosquitto reads the end, and on_disconnect says why
    broker_.next_layer().close(ignored);
}

}  // namespace ioport::daemon
