#include "daemon/sparkplug/sparkplug_output.hpp"

namespace ioport::daemon {

SparkplugOutput::SparkplugOutput(const asio::any_io_executor& executor, Log& log, EventBus& bus,
                                 WorkerThread& disk)
    : executor_(executor), log_(log), bus_(bus), disk_(disk) {}

Result<> SparkplugOutput::start_node(const config::GatewayConfig& config, const Links& links) {
    settings_ = config.mqtt;
    if (!settings_) return {};
    auto node = SparkplugNode::create(executor_, *settings_, log_, bus_, disk_, next_bdseq_);
    if (!node) return Unexpected(node.error());
    node_ = std::move(*node);
    node_->set_read_only(config.modbus.read_only);
    node_->start(links);
    return {};
}

Result<> SparkplugOutput::start(const config::GatewayConfig& config, const Links& links) {
    return start_node(config, links);
}

Result<> SparkplugOutput::prepare(const config::GatewayConfig& next) {
    if (next.mqtt && next.mqtt->store && next.mqtt != settings_)
        return check_store_directory(next.mqtt->store->path);
    return {};
}

bool SparkplugOutput::apply(const config::GatewayConfig& next, const Links& links) {
    if (next.mqtt == settings_) {
        if (node_) {
            node_->set_read_only(next.modbus.read_only);
            node_->set_links(links);
        }
        return false;
    }
    // Another broker or node: this session ends cleanly (NDEATH), a new one begins, its bdSeq
    // going on from this one's, as bdSeq counts every CONNECT of the process.
    if (node_) {
        next_bdseq_ = node_->next_bdseq();
        node_->stop(output_stop_deadline, [] {});
    }
    node_.reset();
    if (auto started = start_node(next, links); !started)
        log_.error({}, "SIGHUP: Sparkplug not started: {}", started.error().message);
    return true;
}

void SparkplugOutput::stop(std::chrono::milliseconds deadline, std::function<void()> done) {
    if (node_)
        node_->stop(deadline, std::move(done));
    else
        done();
}

void SparkplugOutput::metrics(Exposition& out) const {
    if (!node_) return;  // MQTT off: no such families
    const auto stats = node_->stats();
    connection_families(out, "ioportd_mqtt", "Sparkplug B's MQTT",
                        {stats.connected, stats.published, stats.dropped});
    out.family("ioportd_sparkplug_online", "gauge",
               "1 while the edge node's births are out in the current session");
    out.sample("ioportd_sparkplug_online", {}, stats.online ? 1 : 0);
    out.family("ioportd_sparkplug_births_total", "counter", "NBIRTHs sent, rebirths included");
    out.sample("ioportd_sparkplug_births_total", {}, stats.births);
    out.family("ioportd_sparkplug_commands_total", "counter", "DCMD metrics received, by result");
    out.sample("ioportd_sparkplug_commands_total", {{"result", "accepted"}},
               stats.commands - stats.commands_refused - stats.commands_unknown_device);
    out.sample("ioportd_sparkplug_commands_total", {{"result", "refused"}}, stats.commands_refused);
    out.sample("ioportd_sparkplug_commands_total", {{"result", "unknown_device"}},
               stats.commands_unknown_device);
    out.family("ioportd_sparkplug_host_states_total", "counter",
               "STATE messages of the primary host, by result (ahead: taken, its timestamp too "
               "far ahead of this clock to order later ones)");
    out.sample("ioportd_sparkplug_host_states_total", {{"result", "taken"}}, stats.states.taken);
    out.sample("ioportd_sparkplug_host_states_total", {{"result", "ahead"}}, stats.states.ahead);
    out.sample("ioportd_sparkplug_host_states_total", {{"result", "stale"}}, stats.states.stale);
    out.sample("ioportd_sparkplug_host_states_total", {{"result", "refused"}},
               stats.states.refused);
    if (!stats.store) return;  // no store: no such families
    const auto& store = *stats.store;
    out.family("ioportd_sparkplug_store_bytes", "gauge", "Bytes of the store's files on disk");
    out.sample("ioportd_sparkplug_store_bytes", {}, store.bytes);
    out.family("ioportd_sparkplug_store_records", "gauge",
               "Stored DDATA messages the broker does not have yet");
    out.sample("ioportd_sparkplug_store_records", {}, store.records);
    out.family("ioportd_sparkplug_store_dropped_total", "counter",
               "Stored DDATA messages lost: the oldest beyond max_size, or the disk did not take "
               "them");
    out.sample("ioportd_sparkplug_store_dropped_total", {}, store.dropped);
    out.family("ioportd_sparkplug_forwarded_total", "counter",
               "Stored DDATA messages forwarded that the broker is known to have");
    out.sample("ioportd_sparkplug_forwarded_total", {}, store.forwarded);
}

void SparkplugOutput::state(Json& json) const {
    json.key("sparkplug");
    if (!node_) {
        json.null();
        return;
    }
    const auto stats = node_->stats();
    json.begin_object()
        .member("broker", node_->broker())
        .member("group_id", node_->settings().group_id)
        .member("edge_node_id", node_->settings().edge_node_id)
        .member("connected", stats.connected)
        .member("online", stats.online)
        .member("bdseq", stats.bdseq)
        .member("published", stats.published)
        .member("dropped", stats.dropped)
        .member("births", stats.births);
    json.key("store");
    if (const auto& store = stats.store) {
        json.begin_object()
            .member("path", node_->settings().store->path)
            .member("bytes", store->bytes)
            .member("records", store->records)
            .member("dropped", store->dropped)
            .member("forwarded", store->forwarded)
            .member("forwarding", stats.forwarding);
        json.key("oldest");
        if (stats.backlog_oldest_ms)
            json.value(*stats.backlog_oldest_ms);
        else
            json.null();
        json.end_object();
    } else {
        json.null();
    }
    json.end_object();
}

}  // namespace ioport::daemon
