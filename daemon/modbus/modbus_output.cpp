#include "daemon/modbus/modbus_output.hpp"

#include "protocol/request_labels.hpp"

namespace ioport::daemon {

ModbusOutput::ModbusOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus,
                           std::shared_ptr<CommLossWatch> comm_loss)
    : executor_(executor), log_(log), bus_(bus), comm_loss_(std::move(comm_loss)) {}

Result<> ModbusOutput::start(const config::GatewayConfig& config, const Links& links) {
    server_ =
        std::make_shared<ModbusServer>(executor_, config.modbus, links, log_, bus_, comm_loss_);
    return server_->start();
}

Result<> ModbusOutput::prepare(const config::GatewayConfig& next) {
    return server_->prepare(next.modbus);
}

void ModbusOutput::abandon() {
    server_->abandon();
}

bool ModbusOutput::apply(const config::GatewayConfig& next, const Links& links) {
    const bool changed = !(next.modbus == server_->settings());
    server_->apply(next.modbus, links);
    return changed;
}

void ModbusOutput::stop(std::chrono::milliseconds deadline, std::function<void()> done) {
    if (server_) {
        if (deadline.count() > 0)
            server_->shut_down();
        else
            server_->stop();
    }
    done();
}

void ModbusOutput::metrics(Exposition& out) const {
    const auto& server = *server_;
    const auto& stats = server.stats();
    out.family("ioportd_modbus_connections", "gauge", "Modbus client connections open now");
    out.sample("ioportd_modbus_connections", {}, static_cast<std::uint64_t>(server.connections()));
    out.family("ioportd_modbus_connections_refused_total", "counter",
               "Modbus connections refused at accept, by reason");
    out.sample("ioportd_modbus_connections_refused_total", {{"reason", "not_allowed"}},
               stats.refused_not_allowed);
    out.sample("ioportd_modbus_connections_refused_total", {{"reason", "too_many"}},
               stats.refused_too_many);
    out.sample("ioportd_modbus_connections_refused_total", {{"reason", "tls_handshake"}},
               stats.refused_tls_handshake);
    out.sample("ioportd_modbus_connections_refused_total", {{"reason", "too_many_handshakes"}},
               stats.refused_too_many_handshakes);
    out.family(
        "ioportd_modbus_requests_total", "counter",
        "Modbus requests answered, by configured unit id and function code, the rest as other");
    for (const auto& [key, count] : stats.responses.requests())
        out.sample("ioportd_modbus_requests_total",
                   {{"unit", gateway::label_text(key.first)},
                    {"function", gateway::label_text(key.second)}},
                   count);
    out.family(
        "ioportd_modbus_exceptions_total", "counter",
        "Modbus exception responses, by configured unit id and exception code, the rest as other");
    for (const auto& [key, count] : stats.responses.exceptions())
        out.sample(
            "ioportd_modbus_exceptions_total",
            {{"unit", gateway::label_text(key.first)}, {"code", gateway::label_text(key.second)}},
            count);
    const auto& histogram = stats.request_duration;
    out.family("ioportd_modbus_request_duration_seconds", "histogram",
               "From a request's last byte received to its response sent");
    for (std::size_t i = 0; i < histogram.bounds().size(); ++i)
        out.sample("ioportd_modbus_request_duration_seconds_bucket",
                   {{"le", fmt::format("{}", histogram.bounds()[i])}}, histogram.cumulative(i));
    out.sample("ioportd_modbus_request_duration_seconds_bucket", {{"le", "+Inf"}},
               histogram.count());
    out.sample("ioportd_modbus_request_duration_seconds_sum", {}, histogram.sum());
    out.sample("ioportd_modbus_request_duration_seconds_count", {}, histogram.count());
    out.family("ioportd_comm_loss", "gauge",
               "1 while outputs are in their safe state after a communication loss (5.3)");
    out.sample("ioportd_comm_loss", {}, server.comm_lost() ? 1 : 0);
}

void ModbusOutput::state(Json& json) const {
    const auto& server = *server_;
    const auto& settings = server.settings();
    json.key("modbus")
        .begin_object()
        .member("listen", settings.plain() ? host_port(server.local_endpoint()) : std::string())
        .member("tls_listen", settings.tls ? host_port(server.tls_endpoint()) : std::string())
        .member("connections", static_cast<std::uint64_t>(server.connections()))
        .member("handshakes", static_cast<std::uint64_t>(server.handshakes()))
        .member("max_connections", settings.max_connections)
        .member("comm_loss", server.comm_lost());
    json.key("refused")
        .begin_object()
        .member("not_allowed", server.stats().refused_not_allowed)
        .member("too_many", server.stats().refused_too_many)
        .member("tls_handshake", server.stats().refused_tls_handshake)
        .member("too_many_handshakes", server.stats().refused_too_many_handshakes)
        .end_object();
    json.key("clients").begin_array();
    for (const auto& client : server.clients())
        json.begin_object()
            .member("address", client.address)
            .member("since", rfc3339(client.since))
            .member("requests", client.requests)
            .member("transport", client.tls ? "tls" : "tcp")
            .member("role", client.role)
            .end_object();
    json.end_array().end_object();
}

}  // namespace ioport::daemon
