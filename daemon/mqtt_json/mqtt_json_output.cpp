#include "daemon/mqtt_json/mqtt_json_output.hpp"

namespace ioport::daemon {

MqttJsonOutput::MqttJsonOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus)
    : executor_(executor), log_(log), bus_(bus) {}

Result<> MqttJsonOutput::start_session(const config::GatewayConfig& config, const Links& links) {
    settings_ = config.mqtt_json;
    if (!settings_) return {};
    auto session = MqttJsonSession::create(executor_, *settings_, log_, bus_);
    if (!session) return Unexpected(session.error());
    session_ = std::move(*session);
    session_->set_read_only(config.modbus.read_only);
    session_->start(links);
    return {};
}

Result<> MqttJsonOutput::start(const config::GatewayConfig& config, const Links& links) {
    return start_session(config, links);
}

Result<> MqttJsonOutput::prepare(const config::GatewayConfig& /*next*/) {
    return {};
}

bool MqttJsonOutput::apply(const config::GatewayConfig& next, const Links& links) {
    if (next.mqtt_json == settings_) {
        if (session_) {
            session_->set_read_only(next.modbus.read_only);
            session_->set_links(links);
        }
        return false;
    }
    // Another broker or prefix: this session ends cleanly (offline), a new one begins.
    if (session_) session_->stop(output_stop_deadline, [] {});
    session_.reset();
    if (auto started = start_session(next, links); !started)
        log_.error({}, "SIGHUP: MQTT JSON output not started: {}", started.error().message);
    return true;
}

void MqttJsonOutput::stop(std::chrono::milliseconds deadline, std::function<void()> done) {
    if (session_)
        session_->stop(deadline, std::move(done));
    else
        done();
}

void MqttJsonOutput::metrics(Exposition& out) const {
    if (!session_) return;  // MQTT JSON off: no such families
    const auto stats = session_->stats();
    connection_families(out, "ioportd_mqtt_json", "the MQTT JSON output",
                        {stats.connected, stats.published, stats.dropped});
    out.family("ioportd_mqtt_json_sets_total", "counter", "set messages received, by result");
    out.sample("ioportd_mqtt_json_sets_total", {{"result", "accepted"}},
               stats.sets - stats.sets_refused);
    out.sample("ioportd_mqtt_json_sets_total", {{"result", "refused"}}, stats.sets_refused);
    out.family("ioportd_mqtt_json_discovery_cleared_total", "counter",
               "Home Assistant discovery configs cleared: their module is no longer configured");
    out.sample("ioportd_mqtt_json_discovery_cleared_total", {}, stats.discovery_cleared);
    out.family("ioportd_mqtt_json_bridge_requests_total", "counter",
               "bridge requests received (gateway.md §7.3), by result");
    out.sample("ioportd_mqtt_json_bridge_requests_total", {{"result", "answered"}},
               stats.requests - stats.requests_dropped);
    out.sample("ioportd_mqtt_json_bridge_requests_total", {{"result", "dropped"}},
               stats.requests_dropped);
}

void MqttJsonOutput::state(Json& json) const {
    json.key("mqtt_json");
    if (!session_) {
        json.null();
        return;
    }
    const auto stats = session_->stats();
    const auto& settings = session_->settings();
    json.begin_object()
        .member("broker", session_->broker())
        .member("topic_prefix", settings.topic_prefix)
        .member("discovery_prefix", settings.discovery ? settings.discovery_prefix : "")
        .member("connected", stats.connected)
        .member("published", stats.published)
        .member("dropped", stats.dropped)
        .member("sets", stats.sets)
        .member("sets_refused", stats.sets_refused)
        .member("discovery_cleared", stats.discovery_cleared)
        .end_object();
}

}  // namespace ioport::daemon
