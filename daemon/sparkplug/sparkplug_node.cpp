#include "daemon/sparkplug/sparkplug_node.hpp"

#include <algorithm>

#include <fmt/format.h>

#include "daemon/sparkplug/sparkplug_node_common.hpp"

namespace ioport::daemon {
namespace {

using sparkplug::DataType;
using sparkplug::MessageType;
using sparkplug::Metric;
using sparkplug::Payload;
using sparkplug::Value;
using sparkplug_node::next_server_metric;
using sparkplug_node::now_ms;
using sparkplug_node::rebirth_metric;
using sparkplug_node::shown;
using sparkplug_node::type_of;

// The node metrics' aliases: four per link. bdSeq and the Node Control metrics go by name: an
// NBIRTH MUST NOT give Node Control/Rebirth an alias (Sparkplug 3.0,
// tck-id-operational-behavior-data-commands-rebirth-name-aliases), and a host commands them by
// name.
constexpr std::uint64_t first_link_alias = 0;
constexpr std::uint64_t metrics_per_link = 4;

std::uint32_t wire(DataType type) {
    return static_cast<std::uint32_t>(type);
}

std::optional<Value> metric_value(const std::optional<gateway::PointValue>& value) {
    return value ? std::optional(sparkplug::metric_value(*value)) : std::nullopt;
}

}  // namespace

Result<std::shared_ptr<SparkplugNode>> SparkplugNode::create(
    const asio::any_io_executor& executor, const config::MqttSettings& settings, Log& log,
    EventBus& bus, WorkerThread& disk, std::optional<std::uint64_t> next_bdseq) {
    std::shared_ptr<SparkplugNode> node(new SparkplugNode(executor, settings, log, bus));
    node->next_bdseq_ = next_bdseq.value_or(0) % 256;
    std::weak_ptr<SparkplugNode> weak = node;
    // Nothing larger than a command can be reaches the node, in MQTT 5 or 3.1.1 (MqttClient);
    // in MQTT 5 its DISCONNECT asks for the will too
    // (tck-id-payloads-ndeath-will-message-publisher-disconnect-mqtt50).
    auto client = MqttClient::create(
        executor, settings,
        {.maximum_packet_size = sparkplug_maximum_packet_size,
         .disconnect = MqttClient::Disconnect::with_will},
        "mqtt", log,
        {.connecting =
             [weak] {
                 if (auto self = weak.lock()) self->connecting();
             },
         .connected =
             [weak] {
                 if (auto self = weak.lock()) self->connected();
             },
         .disconnected =
             [weak](const std::string&) {
                 if (auto self = weak.lock()) self->disconnected();
             },
         .message =
             [weak](std::string_view topic, std::span<const std::uint8_t> payload, bool) {
                 if (auto self = weak.lock()) self->message(topic, payload);
             },
         .subscribed =
             [weak](int mid) {
                 if (auto self = weak.lock()) self->subscribed(mid);
             },
         .too_large =
             [weak](std::string_view topic, std::uint64_t bytes) {
                 if (auto self = weak.lock()) self->too_large(topic, bytes);
             }});
    if (!client) return Unexpected(client.error());
    node->client_ = std::move(*client);
    if (const auto& store = settings.store) {
        // A directory others could write into is refused here, at start-up or before a reload
        // changes anything (gateway.md §6.2); one whose files then cannot be read costs the
        // history, never the live data (SparkplugStore logs it).
        auto opened = SparkplugStore::open(executor, disk, *store, log, [weak] {
            if (auto self = weak.lock()) self->store_ready();
        });
        if (!opened) return Unexpected(opened.error());
        node->store_ = std::move(*opened);
        // A restart goes on from the last run's bdSeq: a late will of that run never carries
        // the new session's (issue 49).
        if (!next_bdseq)
            if (const auto saved = node->store_->saved_bdseq()) node->next_bdseq_ = *saved;
    }
    return node;
}

SparkplugNode::SparkplugNode(const asio::any_io_executor& executor, config::MqttSettings settings,
                             Log& log, EventBus& bus)
    : executor_(executor),
      settings_(std::move(settings)),
      log_(log),
      bus_(bus),
      ticker_(executor),
      rebirth_timer_(executor),
      host_online_(settings_.primary_host_id.empty()),
      forward_timer_(executor),
      proof_timer_(executor),
      host_timer_(executor) {}

void SparkplugNode::start(const Links& links) {
    build(links);
    log_.info({}, "Sparkplug B edge node {}/{} on {}{}", settings_.group_id, settings_.edge_node_id,
              client_->broker(),
              settings_.primary_host_id.empty()
                  ? std::string()
                  : fmt::format(", births wait for primary host {}", settings_.primary_host_id));
    client_->start();
    tick();
}

void SparkplugNode::build(const Links& links) {
    links_ = links;
    devices_.clear();
    devices_of_.clear();
    links_published_.clear();
    std::uint64_t alias = first_link_alias + metrics_per_link * links.size();
    for (const auto& link : links) {
        links_published_.push_back(link_metrics(*link));
        const auto first = devices_.size();
        for (const auto& view : link->modules()) {
            Device device{link,
                          view.slot,
                          view.address,
                          sparkplug::device_id(link->config().name, view.address,
                                               settings_.device_id_separator),
                          sparkplug::module_metrics(type_of(view.address)),
                          alias,
                          *view.tags,
                          sparkplug::module_properties(view.address, *view.tags)};
            alias += device.metrics.size();
            devices_.push_back(std::move(device));
        }
        devices_of_[link.get()] = {first, devices_.size()};
    }
    watch_links();
}

void SparkplugNode::watch_links() {
    const std::weak_ptr<SparkplugNode> weak = shared_from_this();
    subscription_ = watch_module_data(bus_, links_, [weak](const LinkScheduler* link, int slot) {
        if (auto self = weak.lock()) self->changed(link, slot);
    });
}

void SparkplugNode::set_links(const Links& links) {
    const auto map_of = [this](const Links& of) {
        std::vector<std::string> ids;
        for (const auto& link : of)
            for (const auto& view : link->modules())
                ids.push_back(sparkplug::device_id(link->config().name, view.address,
                                                   settings_.device_id_separator));
        return ids;
    };
    const bool same_map = map_of(links) == map_of(links_);
    const auto same_tags = [&] {
        for (const auto& device : devices_)
            for (const auto& link : links)
                if (link->config().name == device.link->config().name)
                    if (const auto* view = link->module_at(device.slot);
                        view != nullptr && *view->tags != device.tags)
                        return false;
        return true;
    };
    if (same_map && same_tags()) {
        // Restarted links are new objects with the same modules: only watched anew.
        for (auto& device : devices_)
            for (const auto& link : links)
                if (link->config().name == device.link->config().name) device.link = link;
        links_ = links;
        watch_links();
        return;
    }
    const auto types_of = [](const std::vector<Device>& of) {
        std::vector<std::string> types;
        types.reserve(of.size());
        for (const auto& device : of)
            types.push_back(sparkplug::template_name(type_of(device.module)));
        std::ranges::sort(types);
        types.erase(std::unique(types.begin(), types.end()), types.end());
        return types;
    };
    const auto types_before = types_of(devices_);
    build(links);
    if (born_) {
        log_.info({}, "Sparkplug: {} changed; new births",
                  same_map ? "names, units or scales"
                  : settings_.templates && types_of(devices_) != types_before
                      ? "the module map and its template types"
                      : "the module map");
        birth();
    }
}

void SparkplugNode::stop(std::chrono::milliseconds deadline, std::function<void()> done) {
    stopping_ = true;
    ticker_.cancel();
    rebirth_timer_.cancel();
    forward_timer_.cancel();
    proof_timer_.cancel();
    proof_timer_armed_ = false;
    host_timer_.cancel();
    subscription_.reset();
    // The will is for an unexpected end; a clean one says so itself (Sparkplug 3.0 §7.3).
    if (client_->connected()) publish_death();
    born_ = false;
    // Closed on the disk thread after what it was given there, synced: a reload's new node scans
    // the same directory only after that.
    store_.reset();
    client_->stop(deadline, std::move(done));
}

SparkplugStats SparkplugNode::stats() const {
    auto stats = stats_;
    stats.connected = client_->connected();
    stats.online = born_;
    stats.bdseq = bdseq_;
    stats.published = client_->published();
    stats.dropped = client_->dropped();
    stats.forwarding = forward_started_.has_value();
    if (store_) {
        stats.store = store_->stats();
        if (store_->pending()) stats.backlog_oldest_ms = backlog_oldest_ms_;
    }
    return stats;
}

std::vector<std::uint8_t> SparkplugNode::death_payload() const {
    return sparkplug::encode(Payload{
        now_ms(),
        std::nullopt,
        {Metric{"bdSeq", std::nullopt, std::nullopt, wire(DataType::int64), Value(bdseq_)}}});
}

// Queued even beyond the client's bound: in MQTT 3.1.1 the DISCONNECT that follows discards the
// will, so an NDEATH dropped here would leave the host believing the node alive. (In MQTT 5 the
// DISCONNECT asks for the will as well; this one, made now, still comes first.)
void SparkplugNode::publish_death() {
    if (!client_->publish(
            sparkplug::topic(settings_.group_id, MessageType::ndeath, settings_.edge_node_id),
            death_payload(), 1, false, MqttClient::Bound::none))
        log_.warn({}, "Sparkplug: NDEATH could not be queued; the broker's will announces the end");
}

void SparkplugNode::connecting() {
    // A new bdSeq for each CONNECT that goes out; an attempt whose CONNECT never did (the name
    // not resolved, the TCP connection refused, no TLS) spent none, as no broker saw its will.
    if (bdseq_spent_) {
        bdseq_ = next_bdseq_;
        next_bdseq_ = (next_bdseq_ + 1) % 256;
        if (store_) store_->save_bdseq(next_bdseq_);
    }
    bdseq_spent_ = true;
    const auto death = death_payload();
    const auto will = client_->set_will(
        sparkplug::topic(settings_.group_id, MessageType::ndeath, settings_.edge_node_id), death, 1,
        false);
    if (!will)
        log_.error({}, "Sparkplug: {}: a lost session will not be announced by NDEATH",
                   will.error().message);
}

void SparkplugNode::connected() {
    ++session_;
    born_ = false;
    proofs_.clear();
    live_proofs_.clear();
    if (store_) forward_sent_ = store_->delivered();
    for (auto& device : devices_)
        device.born = false;
    const auto& group = settings_.group_id;
    const auto& node = settings_.edge_node_id;
    // Until the SUBACK of the last of them, no births and so no DATA: what changes meanwhile
    // goes to the store. A broker that takes the CONNECT but closes the connection at a
    // SUBSCRIBE (RabbitMQ, while the node of the session's queue is down) once had the live
    // DDATA of that moment, lost with the connection (issue 49).
    births_await_suback_.reset();
    std::optional<int> last;
    const auto subscribe_to = [&](const std::string& topic, std::string_view what) {
        if (const auto mid = subscribe(topic, what)) last = mid;
    };
    subscribe_to(sparkplug::topic(group, MessageType::ncmd, node), "commands (NCMD)");
    subscribe_to(sparkplug::topic(group, MessageType::dcmd, node, "+"), "commands (DCMD)");
    // And two levels or more, apart: a DCMD whose device id a broker split into levels
    // (RabbitMQ makes hub0.dim16.0 hub0/dim16/0) arrives, to be counted and said, not lost
    // unseen. Not one "#" for both: Sparkplug 3.0 names the subscription above.
    subscribe_to(sparkplug::topic(group, MessageType::dcmd, node, "+/+/#"),
                 "DCMDs to no device (device ids split into levels)");
    if (!settings_.primary_host_id.empty()) {
        host_online_ = false;  // until its STATE says so (retained, so it comes at once)
        // Timestamps are compared within a connection: the host's STATE on this broker may be
        // older than the one it left on the last.
        host_state_timestamp_ = 0;
        subscribe_to(sparkplug::state_topic(settings_.primary_host_id), "the primary host's STATE");
        births_await_suback_ = last;
        if (settings_.brokers.size() > 1) {
            // A host that is not on this broker at all: no STATE within keepalive.
            host_timer_.expires_after(settings_.keepalive);
            host_timer_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
                auto self = weak.lock();
                if (!self || ec || self->host_online_) return;
                self->walk(fmt::format(
                    "no STATE of the primary host {} within {} s", self->settings_.primary_host_id,
                    std::chrono::duration_cast<std::chrono::seconds>(self->settings_.keepalive)
                        .count()));
            });
        }
        return;
    }
    births_await_suback_ = last;
    birth();
}

// Sparkplug 3.0 §7.1: an edge node leaves a broker its primary host is not on, or when the host
// asks, for the next in its list: NDEATH first, then DISCONNECT.
void SparkplugNode::walk(const std::string& why) {
    if (stopping_ || !client_->connected()) return;
    log_.warn({}, "Sparkplug: {}; NDEATH, and {}", why,
              settings_.brokers.size() > 1
                  ? fmt::format("leaving {} for the next broker", client_->broker())
                  : fmt::format("connecting to {} again", client_->broker()));
    host_timer_.cancel();
    publish_death();
    born_ = false;
    client_->walk();
}

// The SUBSCRIBE's message id; none when it could not be sent (logged).
std::optional<int> SparkplugNode::subscribe(const std::string& topic, std::string_view what) {
    auto subscribed = client_->subscribe(topic, 1);
    if (subscribed) return *subscribed;
    log_.error({}, "Sparkplug: {}: {} will not arrive in this session", subscribed.error().message,
               what);
    return std::nullopt;
}

void SparkplugNode::disconnected() {
    if (!client_->connect_sent()) bdseq_spent_ = false;
    ++session_;
    born_ = false;
    births_await_suback_.reset();
    for (auto& device : devices_)
        device.born = false;
    // What the broker did not provably get goes out again in the next session: the live DDATA
    // first, before anything that changes from now on goes to the store.
    keep_unproven();
    proofs_.clear();
    forward_timer_.cancel();
    host_timer_.cancel();
    // A rebirth asked for in the lost session is the next session's births; what changes till
    // then goes to the store.
    rebirth_timer_.cancel();
    rebirth_waiting_ = false;
    if (forward_started_) {
        log_.warn({},
                  "Sparkplug: forwarding interrupted after {} record(s); it resumes after the "
                  "last one the broker is known to have",
                  forwarded_in_run_);
        forward_started_.reset();
    }
}

std::uint64_t SparkplugNode::next_seq() {
    seq_ = (seq_ + 1) % 256;
    return seq_;
}

bool SparkplugNode::publish(MessageType type, std::string_view device, const Payload& payload,
                            int qos) {
    const bool data = type == MessageType::ndata || type == MessageType::ddata;
    const auto bytes = sparkplug::encode(
        payload, data ? sparkplug::Datatypes::left_out : sparkplug::Datatypes::sent);
    const bool sent =
        client_->publish(sparkplug::topic(settings_.group_id, type, settings_.edge_node_id, device),
                         bytes, qos, false);
    if (!sent && client_->connected() && !rebirth_due_) {
        rebirth_due_ = true;
        log_.warn({},
                  "Sparkplug: the broker takes messages slower than they come; {} dropped "
                  "so far; new births once the queue has drained",
                  client_->dropped());
    }
    return sent;
}

ioport::daemon::SparkplugNode::LinkMetrics SparkplugNode::link_metrics(
    const LinkScheduler& link) const {
    const auto& c = link.counters();
    return {link.config().name, link.port_open(), c.transactions_ok, c.transactions_failed(),
            c.reopens()};
}

void SparkplugNode::birth() {
    if (!client_->connected() || !host_online_ || stopping_ || births_await_suback_) return;
    rebirth_due_ = false;
    seq_ = 0;
    const auto now = now_ms();
    Payload nbirth{now, 0, {}};
    nbirth.metrics.push_back(
        Metric{"bdSeq", std::nullopt, now, wire(DataType::int64), Value(bdseq_)});
    nbirth.metrics.push_back(Metric{std::string(rebirth_metric), std::nullopt, now,
                                    wire(DataType::boolean), Value(false)});
    nbirth.metrics.push_back(Metric{std::string(next_server_metric), std::nullopt, now,
                                    wire(DataType::boolean), Value(false)});
    std::uint64_t alias = first_link_alias;
    for (std::size_t l = 0; l < links_.size(); ++l) {
        const auto current = link_metrics(*links_[l]);
        const auto prefix = fmt::format("link/{}/", current.name);
        nbirth.metrics.push_back(
            Metric{prefix + "up", alias++, now, wire(DataType::boolean), Value(current.up)});
        nbirth.metrics.push_back(Metric{prefix + "transactions_ok", alias++, now,
                                        wire(DataType::uint64), Value(current.ok)});
        nbirth.metrics.push_back(Metric{prefix + "transactions_failed", alias++, now,
                                        wire(DataType::uint64), Value(current.failed)});
        nbirth.metrics.push_back(Metric{prefix + "reopens", alias++, now, wire(DataType::uint64),
                                        Value(current.reopens)});
        links_published_[l] = current;
    }
    if (settings_.templates) definitions(nbirth, now);
    counters_sent_ = std::chrono::steady_clock::now();
    if (!publish(MessageType::nbirth, {}, nbirth)) return;
    last_nbirth_ = counters_sent_;
    ++stats_.births;
    born_ = true;
    int devices = 0;
    for (auto& device : devices_) {
        device.born = false;
        const auto view = device.link->module_at(device.slot);
        if (view && view->status() == gateway::ModuleStatus::online) {
            device_birth(device, *view);
            ++devices;
        }
    }
    log_.info({}, "Sparkplug: NBIRTH (bdSeq {}) and {} DBIRTH(s) of {} devices", bdseq_, devices,
              devices_.size());
    start_forwarding();
}

// One definition per module type configured, in the order of ModuleType, the ID-2's last: the
// same module map gives the same NBIRTH.
void SparkplugNode::definitions(Payload& nbirth, std::uint64_t now) const {
    std::vector<std::optional<ModuleType>> types;
    for (const auto& device : devices_)
        if (std::ranges::find(types, type_of(device.module)) == types.end())
            types.push_back(type_of(device.module));
    std::ranges::sort(types, [](const auto& a, const auto& b) {
        if (!a || !b) return a.has_value() && !b.has_value();  // the ID-2 last
        return static_cast<int>(*a) < static_cast<int>(*b);
    });
    for (const auto& type : types)
        nbirth.metrics.push_back(sparkplug::template_definition(type, now));
}

void SparkplugNode::device_birth(Device& device, const ModuleState& view) {
    const auto now = now_ms();
    const auto& values = view.values;
    Payload payload{now, next_seq(), {}};
    std::vector<Metric> metrics;
    metrics.reserve(device.metrics.size());
    // Flat, each metric by name and alias; with templates, the members by name alone (the
    // instance has the alias), each with its §6.1 properties.
    for (std::size_t i = 0; i < device.metrics.size(); ++i)
        metrics.push_back(Metric{
            device.metrics[i].name,
            settings_.templates ? std::nullopt : std::optional(device.first_alias + i), now,
            wire(device.metrics[i].type), metric_value(values[i]), false, device.properties[i]});
    if (settings_.templates)
        payload.metrics.push_back(sparkplug::template_instance(
            type_of(device.module), std::move(metrics), device.first_alias, now));
    else
        payload.metrics = std::move(metrics);
    if (!publish(MessageType::dbirth, device.id, payload)) return;
    device.published = values;
    device.born = true;
    device.first_unstored.reset();  // the birth carries the values now, newer or not
}

void SparkplugNode::changed(const LinkScheduler* link, int slot) {
    // A rebirth is waiting: nothing until it, and the births carry what changed meanwhile.
    if (rebirth_waiting_) return;
    // Without a session, what would have gone out is kept, when there is a store.
    if (!born_ && (!store_ || stopping_)) return;
    const auto of_link = devices_of_.find(link);
    const auto [first, last] =
        of_link == devices_of_.end() ? std::pair<std::size_t, std::size_t>{} : of_link->second;
    for (auto i = first; i < last; ++i) {
        auto& device = devices_[i];
        if (slot >= 0 && device.slot != slot) continue;
        if (born_)
            update(device);
        else
            keep(device);
    }
    if (born_) link_data(false);
}

// No session can publish: what would have gone out as DDATA goes to the store instead, with the
// metrics by name (aliases belong to a session) and their acquisition time.
void SparkplugNode::keep(Device& device) {
    const auto view = device.link->module_at(device.slot);
    if (!view || view->status() != gateway::ModuleStatus::online) return;
    // A module's first values in this process are no history: the DBIRTH carries them. Stored,
    // they came back after it as historical DDATA repeating the birth, a duplicate sample per
    // metric at every start (they are read before the first CONNACK). But a value that changes
    // before the DBIRTH is in none: then the first values are stored after all, before the
    // change (ioportd started while the broker was away lost them; soak_every_path).
    const bool first =
        std::ranges::none_of(device.published, [](const auto& v) { return v.has_value(); });
    auto data = changes(device, *view, MetricsBy::name);
    if (data.changed.empty()) return;
    if (first) {
        device.first_unstored = data.payload;
        published(device, data);
        return;
    }
    if (device.first_unstored) {
        if (!store_->pending()) backlog_oldest_ms_ = device.first_unstored->timestamp;
        store_->append(sparkplug::encode_stored({device.id, *device.first_unstored}));
        device.first_unstored.reset();
    }
    if (!store_->pending()) backlog_oldest_ms_ = data.payload.timestamp;
    if (store_->append(sparkplug::encode_stored({device.id, data.payload})))
        published(device, data);
}

// The store's scan is done: forwarding starts after the last record the broker is known to have,
// if a session is up already.
void SparkplugNode::store_ready() {
    if (forward_started_) return;
    forward_sent_ = store_->delivered();
    start_forwarding();
}

void SparkplugNode::start_forwarding() {
    if (!store_ || !store_->ready() || !born_ || forward_started_ || !store_->pending()) return;
    forward_started_ = std::chrono::steady_clock::now();
    forwarded_in_run_ = 0;
    const auto stats = store_->stats();
    log_.info({}, "Sparkplug: forwarding {} stored record(s){}, at most {} a second", stats.records,
              backlog_oldest_ms_
                  ? fmt::format(", the oldest {} s old", (now_ms() - *backlog_oldest_ms_) / 1000)
                  : std::string(),
              store_->settings().forward_rate);
    forward_tick();
}

// At most forward_rate historical DDATA a second, a tenth of a second's worth at a time (one at
// least), beside the live data, which never waits for them.
void SparkplugNode::forward_tick() {
    if (!born_ || stopping_ || !forward_started_) return;
    const auto rate = static_cast<std::uint64_t>(store_->settings().forward_rate);
    const auto interval =
        std::max(std::chrono::milliseconds(100), std::chrono::milliseconds(1000 / rate));
    forward_timer_.expires_after(interval);
    forward_timer_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        if (auto self = weak.lock(); self && !ec) self->forward_tick();
    });
    // The disk is slow, or a rebirth waits: this tick's share is skipped.
    if (forward_reading_ || rebirth_waiting_) return;
    // At most forward_rate (10000) records: a size_t on every architecture.
    const auto count = static_cast<std::size_t>(
        std::max<std::uint64_t>(1, rate * static_cast<std::uint64_t>(interval.count()) / 1000));
    forward_reading_ = true;
    store_->read_after(
        forward_sent_, count,
        [weak = weak_from_this(), session = session_](std::vector<StoredRecord> records) {
            if (auto self = weak.lock()) self->forward(session, std::move(records));
        });
}

void SparkplugNode::forward(std::uint64_t session, std::vector<StoredRecord> records) {
    forward_reading_ = false;
    if (session != session_ || !born_ || !forward_started_ || rebirth_waiting_) return;
    std::uint64_t sent = 0;
    for (auto& record : records) {
        auto data = sparkplug::decode_stored(record.body);
        const auto device =
            data ? std::ranges::find(devices_, data->device, &Device::id) : devices_.end();
        if (device != devices_.end()) {
            // DDATA only after its device's DBIRTH: a module offline now holds the backlog
            // back until it is born again.
            if (!device->born) break;
            if (sent == 0) backlog_oldest_ms_ = data->payload.timestamp;
            // Records are flat, by name; they go out in the form this session's births gave.
            auto metrics = sparkplug::to_flat(std::move(data->payload.metrics));
            for (auto& metric : metrics) {
                metric.is_historical = true;
                if (!settings_.templates) by_alias(*device, metric);
            }
            if (settings_.templates) {
                auto instance =
                    sparkplug::template_instance(type_of(device->module), std::move(metrics),
                                                 device->first_alias, data->payload.timestamp);
                instance.name.clear();
                instance.is_historical = true;
                metrics = {std::move(instance)};
            }
            data->payload.metrics = std::move(metrics);
            data->payload.seq = next_seq();
            if (!publish(MessageType::ddata, data->device, data->payload)) break;
        } else if (const auto held =
                       refusals_.admit("store record", std::chrono::steady_clock::now())) {
            // Not ours (a good checksum over another body), or of a module no longer configured.
            log_.warn({}, "Sparkplug store: record {} skipped: {}{}", record.number,
                      data ? fmt::format("device {} is not configured now", shown(data->device))
                           : data.error().message,
                      held_back(*held));
        }
        forward_sent_ = record.number;
        ++sent;
    }
    if (sent > 0) {
        // SUBACK proves the broker read everything before the SUBSCRIBE (the same connection
        // keeps its packets in order): those records may go. The NCMD subscription is one the
        // node has anyway, so repeating it changes nothing at the broker.
        const auto mid = client_->subscribe(
            sparkplug::topic(settings_.group_id, MessageType::ncmd, settings_.edge_node_id), 1);
        if (mid) {
            proofs_[*mid] = Proof{forward_sent_, sent};
            live_proofs_[*mid] = unproven_.mark();  // the live DDATA before it, too
        }
    }
    // Over when nothing is left after what was sent and the store holds nothing undelivered:
    // its mark only moves on a SUBACK, so the broker has had every record. A proof still
    // waiting then covers delivered records only (a SUBACK that never came), and goes too.
    if (records.empty() && !store_->pending()) {
        const auto took =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - *forward_started_);
        log_.info({}, "Sparkplug: forwarded {} stored record(s) in {:.1f} s{}", forwarded_in_run_,
                  took.count(),
                  proofs_.empty() ? std::string()
                                  : fmt::format(" ({} SUBACK(s) still awaited)", proofs_.size()));
        proofs_.clear();
        forward_started_.reset();
        backlog_oldest_ms_.reset();
        forward_timer_.cancel();
    }
}

// Stored by name (aliases belong to a session), sent by this session's alias alone, as live
// DDATA is (Sparkplug 3.0 payloads-alias-data-cmd-requirement).
void SparkplugNode::by_alias(const Device& device, Metric& metric) {
    const auto spec = std::ranges::find(device.metrics, metric.name, &sparkplug::MetricSpec::name);
    if (spec == device.metrics.end()) return;  // not the device's: the host will say so
    metric.alias = device.first_alias + static_cast<std::uint64_t>(spec - device.metrics.begin());
    metric.name.clear();
}

void SparkplugNode::subscribed(int mid) {
    if (births_await_suback_ == mid) {
        births_await_suback_.reset();
        birth();  // with a primary host, once its STATE says online
        return;
    }
    if (const auto live = live_proofs_.find(mid); live != live_proofs_.end()) {
        unproven_.proven(live->second);
        live_proofs_.erase(live);
        client_->session_established();  // the broker read what followed the births
        prove_live();
    }
    const auto proof = proofs_.find(mid);
    if (proof == proofs_.end()) return;
    client_->session_established();
    store_->deliver(proof->second.through, proof->second.records);
    forwarded_in_run_ += proof->second.records;
    proofs_.erase(proof);
}

void SparkplugNode::update(Device& device) {
    const auto view = device.link->module_at(device.slot);
    if (!view) return;
    const bool online = view->status() == gateway::ModuleStatus::online;
    if (!online) {
        if (device.born &&
            publish(MessageType::ddeath, device.id, Payload{now_ms(), next_seq(), {}}))
            device.born = false;
        return;
    }
    if (!device.born) {
        device_birth(device, *view);
        return;
    }
    auto data = changes(device, *view, MetricsBy::alias);
    if (data.changed.empty()) return;
    data.payload.seq = next_seq();
    if (!publish(MessageType::ddata, device.id, data.payload)) return;
    published(device, data);
    if (store_) sent_live(device, data);
}

void SparkplugNode::sent_live(const Device& device, const Changes& data) {
    SentData sent{device.id, type_of(device.module), data.payload.timestamp, {}};
    sent.points.reserve(data.changed.size());
    for (const auto i : data.changed)
        sent.points.emplace_back(static_cast<std::uint32_t>(i), data.values[i]);
    unproven_.sent(std::move(sent));
    if (unproven_.forgotten() != forgotten_logged_)
        if (const auto held = refusals_.admit("unproven", std::chrono::steady_clock::now())) {
            log_.warn({},
                      "Sparkplug: {} live DDATA wait for the broker to prove it read them; the "
                      "oldest {} were let go unproven, beyond {} KiB (a connection lost now "
                      "may lose them){}",
                      unproven_.size(), unproven_.forgotten() - forgotten_logged_,
                      max_unproven_bytes >> 10, held_back(*held));
            forgotten_logged_ = unproven_.forgotten();
        }
    prove_live();
}

// A SUBSCRIBE's SUBACK proves the broker read every live DDATA sent before it: one in flight at a
// time, the next live_proof_interval after the last was answered, and none while nothing waits
// for one. The NCMD subscription is one the node has anyway (as forward()'s proofs).
void SparkplugNode::prove_live() {
    if (unproven_.empty() || !live_proofs_.empty() || proof_timer_armed_ || stopping_) return;
    proof_timer_armed_ = true;
    proof_timer_.expires_after(live_proof_interval);
    proof_timer_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        auto self = weak.lock();
        if (!self || ec) return;  // cancelled: whoever cancelled it disarmed it
        self->proof_timer_armed_ = false;
        self->send_live_proof();
    });
}

void SparkplugNode::send_live_proof() {
    if (stopping_ || !client_->connected() || unproven_.empty() || !live_proofs_.empty()) return;
    const auto mid = client_->subscribe(
        sparkplug::topic(settings_.group_id, MessageType::ncmd, settings_.edge_node_id), 1);
    if (mid) live_proofs_[*mid] = unproven_.mark();
}

void SparkplugNode::keep_unproven() {
    live_proofs_.clear();
    proof_timer_.cancel();
    proof_timer_armed_ = false;
    if (!store_ || unproven_.empty()) return;
    const auto records = unproven_.take();
    if (records.empty()) return;
    std::size_t kept = 0;
    for (const auto& record : records) {
        if (!store_->pending()) backlog_oldest_ms_ = record.payload.timestamp;
        if (store_->append(sparkplug::encode_stored(record))) ++kept;
    }
    log_.info({},
              "Sparkplug: {} live DDATA the broker had not proven it read kept in the store, for "
              "after the next births (any it did read arrive twice, the second as history)",
              kept);
}

SparkplugNode::Changes SparkplugNode::changes(Device& device, const ModuleState& view,
                                              MetricsBy by) const {
    Changes data{view.values, {}, Payload{now_ms(), std::nullopt, {}}};
    // Never published in this process (kept while no session could take it): all is news.
    if (device.published.size() != data.values.size())
        device.published.assign(data.values.size(), std::nullopt);
    data.changed = gateway::changed_points(type_of(device.module), device.published, data.values,
                                           settings_.deadband);
    const auto now = data.payload.timestamp;
    // With templates, a session's DDATA is the instance (by its alias) holding the members that
    // changed, by name; the store keeps them flat, by name (forward() makes the instance).
    const bool instance = settings_.templates && by == MetricsBy::alias;
    for (const auto i : data.changed) {
        const auto type = wire(device.metrics[i].type);
        switch (by) {
            case MetricsBy::alias:
                data.payload.metrics.push_back(
                    instance
                        ? Metric{device.metrics[i].name, std::nullopt, now, type,
                                 metric_value(data.values[i])}
                        : Metric{
                              {}, device.first_alias + i, now, type, metric_value(data.values[i])});
                break;
            case MetricsBy::name:
                data.payload.metrics.push_back(Metric{device.metrics[i].name, std::nullopt, now,
                                                      type, metric_value(data.values[i])});
                break;
        }
    }
    if (instance && !data.changed.empty()) {
        auto metric = sparkplug::template_instance(
            type_of(device.module), std::move(data.payload.metrics), device.first_alias, now);
        metric.name.clear();  // by alias alone, as DATA goes
        data.payload.metrics = {std::move(metric)};
    }
    return data;
}

void SparkplugNode::published(Device& device, const Changes& data) {
    for (const auto i : data.changed)
        device.published[i] = data.values[i];
}

// NDATA: a link's port state at once, its counters every counter_period, and with any NDATA
// (Sparkplug 3.0 topics-ndata-payload: every metric changed since the last NBIRTH or NDATA).
void SparkplugNode::link_data(bool counters) {
    for (std::size_t l = 0; l < links_.size() && !counters; ++l)
        counters = links_[l]->port_open() != links_published_[l].up;
    const auto now = now_ms();
    Payload payload{now, std::nullopt, {}};
    for (std::size_t l = 0; l < links_.size(); ++l) {
        const auto current = link_metrics(*links_[l]);
        auto& last = links_published_[l];
        const std::uint64_t alias = first_link_alias + metrics_per_link * l;
        if (current.up != last.up)
            payload.metrics.push_back(
                Metric{{}, alias, now, wire(DataType::boolean), Value(current.up)});
        if (counters) {
            if (current.ok != last.ok)
                payload.metrics.push_back(
                    Metric{{}, alias + 1, now, wire(DataType::uint64), Value(current.ok)});
            if (current.failed != last.failed)
                payload.metrics.push_back(
                    Metric{{}, alias + 2, now, wire(DataType::uint64), Value(current.failed)});
            if (current.reopens != last.reopens)
                payload.metrics.push_back(
                    Metric{{}, alias + 3, now, wire(DataType::uint64), Value(current.reopens)});
        }
        if (!payload.metrics.empty()) {
            last.up = current.up;
            if (counters) {
                last.ok = current.ok;
                last.failed = current.failed;
                last.reopens = current.reopens;
            }
        }
    }
    if (payload.metrics.empty()) return;
    payload.seq = next_seq();
    publish(MessageType::ndata, {}, payload);
}

void SparkplugNode::tick() {
    ticker_.expires_after(std::chrono::seconds(1));
    ticker_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        auto self = weak.lock();
        if (ec || !self || self->stopping_) return;
        if (self->born_ && self->rebirth_due_ && self->client_->connected()) self->birth();
        const auto now = std::chrono::steady_clock::now();
        if (self->born_ && !self->rebirth_waiting_ &&
            now - self->counters_sent_ >= counter_period) {
            self->counters_sent_ = now;
            self->link_data(true);
        }
        self->tick();
    });
}

}  // namespace ioport::daemon
