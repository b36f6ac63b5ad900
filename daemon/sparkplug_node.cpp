#include "daemon/sparkplug_node.hpp"

#include <cmath>

#include <fmt/format.h>

namespace ioport::daemon {
namespace {

using sparkplug::DataType;
using sparkplug::MessageType;
using sparkplug::Metric;
using sparkplug::Payload;
using sparkplug::Value;

constexpr std::string_view rebirth_metric = "Node Control/Rebirth";
// The node metrics' aliases: Node Control/Rebirth, then four per link (bdSeq goes by name).
constexpr std::uint64_t rebirth_alias = 0;
constexpr std::uint64_t metrics_per_link = 4;

std::uint64_t now_ms() {
    return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                          std::chrono::system_clock::now().time_since_epoch())
                                          .count());
}

std::uint32_t wire(DataType type) {
    return static_cast<std::uint32_t>(type);
}

sparkplug::ModuleValues values_of(const ModuleView& view) {
    return {view.reading, view.output, view.stop, view.count};
}

std::optional<ModuleType> type_of(const std::optional<ModuleAddress>& module) {
    return module ? std::optional(module->type) : std::nullopt;
}

// Whether `now` differs from what was published enough to publish it: any change, but for a
// Float only beyond the deadband (compared with the last published value, so that a slow drift
// is published once it adds up).
bool differs(const std::optional<Value>& published, const std::optional<Value>& now,
             double deadband) {
    if (published.has_value() != now.has_value()) return true;
    if (!now) return false;
    const auto* before = std::get_if<float>(&*published);
    const auto* after = std::get_if<float>(&*now);
    if (before != nullptr && after != nullptr && deadband > 0)
        return std::fabs(static_cast<double>(*after) - static_cast<double>(*before)) > deadband;
    return *published != *now;
}

std::string value_text(const std::optional<Value>& value) {
    if (!value) return "null";
    return std::visit(
        [](const auto& v) -> std::string {
            using V = std::decay_t<decltype(v)>;
            if constexpr (std::is_same_v<V, bool>)
                return v ? "true" : "false";
            else if constexpr (std::is_same_v<V, std::string>)
                return v;
            else
                return fmt::format("{}", v);
        },
        *value);
}

}  // namespace

Result<std::shared_ptr<SparkplugNode>> SparkplugNode::create(const asio::any_io_executor& executor,
                                                             const config::MqttSettings& settings,
                                                             Log& log, EventLog& events) {
    std::shared_ptr<SparkplugNode> node(new SparkplugNode(executor, settings, log, events));
    std::weak_ptr<SparkplugNode> weak = node;
    auto client = MqttClient::create(
        executor, settings, log,
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
             [weak](std::string_view topic, std::span<const std::uint8_t> payload) {
                 if (auto self = weak.lock()) self->message(topic, payload);
             }});
    if (!client) return Unexpected(client.error());
    node->client_ = std::move(*client);
    return node;
}

SparkplugNode::SparkplugNode(const asio::any_io_executor& executor, config::MqttSettings settings,
                             Log& log, EventLog& events)
    : executor_(executor),
      settings_(std::move(settings)),
      log_(log),
      events_(events),
      ticker_(executor),
      host_online_(settings_.primary_host_id.empty()) {}

SparkplugNode::~SparkplugNode() {
    for (const auto& link : links_)
        link->set_observer(nullptr);
}

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
    for (const auto& link : links_)
        link->set_observer(nullptr);
    links_ = links;
    devices_.clear();
    links_published_.clear();
    std::uint64_t alias = rebirth_alias + 1 + metrics_per_link * links.size();
    for (const auto& link : links) {
        links_published_.push_back(link_metrics(*link));
        for (const auto& view : link->modules()) {
            Device device{link,
                          view.slot,
                          view.address,
                          sparkplug::device_id(link->config().name, view.address),
                          sparkplug::module_metrics(type_of(view.address)),
                          alias};
            alias += device.metrics.size();
            devices_.push_back(std::move(device));
        }
    }
    watch_links();
}

void SparkplugNode::watch_links() {
    const std::weak_ptr<SparkplugNode> weak = shared_from_this();
    for (const auto& link : links_)
        link->set_observer([weak, raw = link.get()](int slot) {
            if (auto self = weak.lock()) self->changed(raw, slot);
        });
}

void SparkplugNode::set_links(const Links& links) {
    const auto map_of = [](const Links& of) {
        std::vector<std::string> ids;
        for (const auto& link : of)
            for (const auto& view : link->modules())
                ids.push_back(sparkplug::device_id(link->config().name, view.address));
        return ids;
    };
    const bool same_map = map_of(links) == map_of(links_);
    if (same_map) {
        // Restarted links are new objects with the same modules: only watched anew.
        for (const auto& link : links_)
            link->set_observer(nullptr);
        for (auto& device : devices_)
            for (const auto& link : links)
                if (link->config().name == device.link->config().name) device.link = link;
        links_ = links;
        watch_links();
        return;
    }
    build(links);
    if (born_) {
        log_.info({}, "Sparkplug: the module map changed; new births");
        birth();
    }
}

void SparkplugNode::stop(std::chrono::milliseconds deadline, std::function<void()> done) {
    stopping_ = true;
    ticker_.cancel();
    for (const auto& link : links_)
        link->set_observer(nullptr);
    if (client_->connected()) {
        // The will is for an unexpected end; a clean one says so itself (Sparkplug 3.0 §7.3).
        const auto death = death_payload();
        client_->publish(
            sparkplug::topic(settings_.group_id, MessageType::ndeath, settings_.edge_node_id),
            death, 1, false);
    }
    born_ = false;
    client_->stop(deadline, std::move(done));
}

SparkplugStats SparkplugNode::stats() const {
    auto stats = stats_;
    stats.connected = client_->connected();
    stats.online = born_;
    stats.bdseq = bdseq_;
    stats.published = client_->published();
    stats.dropped = client_->dropped();
    return stats;
}

std::vector<std::uint8_t> SparkplugNode::death_payload() const {
    return sparkplug::encode(Payload{
        now_ms(),
        std::nullopt,
        {Metric{"bdSeq", std::nullopt, std::nullopt, wire(DataType::int64), Value(bdseq_)}}});
}

void SparkplugNode::connecting() {
    bdseq_ = next_bdseq_;
    next_bdseq_ = (next_bdseq_ + 1) % 256;
    const auto death = death_payload();
    client_->set_will(
        sparkplug::topic(settings_.group_id, MessageType::ndeath, settings_.edge_node_id), death, 1,
        false);
}

void SparkplugNode::connected() {
    born_ = false;
    for (auto& device : devices_)
        device.born = false;
    const auto& group = settings_.group_id;
    const auto& node = settings_.edge_node_id;
    client_->subscribe(sparkplug::topic(group, MessageType::ncmd, node), 1);
    client_->subscribe(sparkplug::topic(group, MessageType::dcmd, node, "+"), 1);
    if (!settings_.primary_host_id.empty()) {
        host_online_ = false;  // until its STATE says so (retained, so it comes at once)
        client_->subscribe(sparkplug::state_topic(settings_.primary_host_id), 1);
        return;
    }
    birth();
}

void SparkplugNode::disconnected() {
    born_ = false;
    for (auto& device : devices_)
        device.born = false;
}

std::uint64_t SparkplugNode::next_seq() {
    seq_ = (seq_ + 1) % 256;
    return seq_;
}

bool SparkplugNode::publish(MessageType type, std::string_view device, Payload payload, int qos) {
    const auto bytes = sparkplug::encode(payload);
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
            c.opens > 0 ? c.opens - 1 : 0};
}

void SparkplugNode::birth() {
    if (!client_->connected() || !host_online_ || stopping_) return;
    rebirth_due_ = false;
    seq_ = 0;
    const auto now = now_ms();
    Payload nbirth{now, 0, {}};
    nbirth.metrics.push_back(
        Metric{"bdSeq", std::nullopt, now, wire(DataType::int64), Value(bdseq_)});
    nbirth.metrics.push_back(Metric{std::string(rebirth_metric), rebirth_alias, now,
                                    wire(DataType::boolean), Value(false)});
    std::uint64_t alias = rebirth_alias + 1;
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
    counters_sent_ = std::chrono::steady_clock::now();
    if (!publish(MessageType::nbirth, {}, std::move(nbirth))) return;
    ++stats_.births;
    born_ = true;
    int devices = 0;
    for (auto& device : devices_) {
        device.born = false;
        const auto view = device.link->module_at(device.slot);
        if (view && view->status == gateway::ModuleStatus::online) {
            device_birth(device, *view);
            ++devices;
        }
    }
    log_.info({}, "Sparkplug: NBIRTH (bdSeq {}) and {} DBIRTH(s) of {} devices", bdseq_, devices,
              devices_.size());
}

void SparkplugNode::device_birth(Device& device, const ModuleView& view) {
    const auto now = now_ms();
    auto values = sparkplug::module_values(type_of(device.module), values_of(view));
    Payload payload{now, next_seq(), {}};
    payload.metrics.reserve(device.metrics.size());
    for (std::size_t i = 0; i < device.metrics.size(); ++i)
        payload.metrics.push_back(Metric{device.metrics[i].name, device.first_alias + i, now,
                                         wire(device.metrics[i].type), values[i]});
    if (!publish(MessageType::dbirth, device.id, std::move(payload))) return;
    device.published = std::move(values);
    device.born = true;
}

void SparkplugNode::changed(const LinkScheduler* link, int slot) {
    if (!born_) return;
    for (auto& device : devices_)
        if (device.link.get() == link && (slot < 0 || device.slot == slot)) update(device);
    link_data(false);
}

void SparkplugNode::update(Device& device) {
    const auto view = device.link->module_at(device.slot);
    if (!view) return;
    const bool online = view->status == gateway::ModuleStatus::online;
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
    const auto values = sparkplug::module_values(type_of(device.module), values_of(*view));
    const auto now = now_ms();
    Payload payload{now, std::nullopt, {}};
    for (std::size_t i = 0; i < values.size(); ++i)
        if (differs(device.published[i], values[i], settings_.deadband))
            payload.metrics.push_back(
                Metric{{}, device.first_alias + i, now, wire(device.metrics[i].type), values[i]});
    if (payload.metrics.empty()) return;
    payload.seq = next_seq();
    const auto changed = payload.metrics;
    if (!publish(MessageType::ddata, device.id, std::move(payload))) return;
    for (const auto& metric : changed)
        device.published[*metric.alias - device.first_alias] = metric.value;
}

// NDATA: a link's port state at once, its counters every counter_period.
void SparkplugNode::link_data(bool counters) {
    const auto now = now_ms();
    Payload payload{now, std::nullopt, {}};
    for (std::size_t l = 0; l < links_.size(); ++l) {
        const auto current = link_metrics(*links_[l]);
        auto& last = links_published_[l];
        const std::uint64_t alias = rebirth_alias + 1 + metrics_per_link * l;
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
    publish(MessageType::ndata, {}, std::move(payload));
}

void SparkplugNode::tick() {
    ticker_.expires_after(std::chrono::seconds(1));
    ticker_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        auto self = weak.lock();
        if (ec || !self || self->stopping_) return;
        if (self->born_ && self->rebirth_due_ && self->client_->connected()) self->birth();
        const auto now = std::chrono::steady_clock::now();
        if (self->born_ && now - self->counters_sent_ >= counter_period) {
            self->counters_sent_ = now;
            self->link_data(true);
        }
        self->tick();
    });
}

void SparkplugNode::message(std::string_view topic_text, std::span<const std::uint8_t> payload) {
    const auto topic = sparkplug::parse_topic(topic_text);
    if (!topic) return;
    if (topic->type == MessageType::state) {
        if (topic->node != settings_.primary_host_id) return;
        const std::string_view json(reinterpret_cast<const char*>(payload.data()), payload.size());
        const auto online = sparkplug::parse_state(json);
        if (!online) {
            log_.warn({}, "Sparkplug: STATE of {} is not {{\"online\": …}}: {}",
                      settings_.primary_host_id, printable(json.substr(0, 80)));
            return;
        }
        const bool was = host_online_;
        host_online_ = *online;
        if (*online && !was) {
            log_.info({}, "Sparkplug: primary host {} online", settings_.primary_host_id);
            birth();
        } else if (!*online && was) {
            log_.warn({}, "Sparkplug: primary host {} offline; births again when it is back",
                      settings_.primary_host_id);
            born_ = false;
        }
        return;
    }
    if (topic->group != settings_.group_id || topic->node != settings_.edge_node_id) return;
    if (topic->type == MessageType::ncmd || topic->type == MessageType::dcmd)
        command(*topic, payload);
}

void SparkplugNode::command(const sparkplug::Topic& topic, std::span<const std::uint8_t> bytes) {
    const auto payload = sparkplug::decode(bytes);
    if (!payload) {
        log_.warn({}, "Sparkplug: {} on {}: {}", to_string(topic.type),
                  sparkplug::topic(topic.group, topic.type, topic.node, topic.device),
                  payload.error().message);
        return;
    }
    if (topic.type == MessageType::ncmd) {
        for (const auto& metric : payload->metrics) {
            const bool rebirth = metric.name == rebirth_metric ||
                                 (metric.name.empty() && metric.alias == rebirth_alias);
            if (rebirth && metric.value == Value(true)) {
                log_.info({}, "Sparkplug: rebirth asked for (NCMD)");
                birth();
            } else {
                log_.warn({}, "Sparkplug: NCMD metric {} ignored: only {} = true is a command",
                          metric.name.empty() ? fmt::format("alias {}", metric.alias.value_or(0))
                                              : metric.name,
                          rebirth_metric);
            }
        }
        return;
    }
    const auto device = std::find_if(devices_.begin(), devices_.end(),
                                     [&](const Device& d) { return d.id == topic.device; });
    if (device == devices_.end()) {
        log_.warn({}, "Sparkplug: DCMD to {}, which this edge node does not have", topic.device);
        ++stats_.commands_refused;
        return;
    }
    for (const auto& metric : payload->metrics)
        device_command(*device, metric);
}

void SparkplugNode::device_command(Device& device, const Metric& metric) {
    ++stats_.commands;
    std::string name = metric.name;
    if (name.empty() && metric.alias && *metric.alias >= device.first_alias &&
        *metric.alias < device.first_alias + device.metrics.size())
        name = device.metrics[*metric.alias - device.first_alias].name;
    const auto value = value_text(metric.value);
    const auto address = fmt::format("{}/{}", device.id, name.empty() ? "?" : name);
    const LogFields fields{
        device.link->config().name, device.link->config().unit_id, {}, "sparkplug"};
    auto plan = sparkplug::plan_command(device.module, name, metric.value);
    if (!plan) {
        ++stats_.commands_refused;
        auto text =
            fmt::format("Sparkplug DCMD {} = {} refused: {}", address, value, plan.error().message);
        log_.warn(fields, "{}", text);
        events_.add(EventKind::write, device.link->config().name, {}, "sparkplug", std::move(text));
        return;
    }
    const auto started = std::chrono::steady_clock::now();
    asio::co_spawn(
        executor_,
        [self = shared_from_this(), link = device.link, plan = std::move(*plan), address, value,
         started]() mutable -> asio::awaitable<void> {
            const bool reaches_device = !plan.changes.empty() || plan.reset_counter;
            const auto result = co_await link->write(std::move(plan));
            if (!reaches_device) co_return;
            const WriteAudit audit{
                .function = "DCMD",
                .address = address,
                .value = value,
                .result = to_string(result),
                .latency_us = std::chrono::duration_cast<std::chrono::microseconds>(
                                  std::chrono::steady_clock::now() - started)
                                  .count()};
            auto text = fmt::format("write by sparkplug to unit {} ({}): DCMD {} = {}: {} in {} ms",
                                    link->config().unit_id, link->config().name, address, value,
                                    audit.result, static_cast<double>(audit.latency_us) / 1000);
            self->log_.notice({.link = link->config().name,
                               .unit = link->config().unit_id,
                               .client = "sparkplug",
                               .audit = &audit},
                              "{}", text);
            self->events_.add(EventKind::write, link->config().name, {}, "sparkplug",
                              std::move(text));
        },
        asio::detached);
}

}  // namespace ioport::daemon
