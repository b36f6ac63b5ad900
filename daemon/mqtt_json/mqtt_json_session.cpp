#include "daemon/mqtt_json/mqtt_json_session.hpp"

#include <algorithm>
#include <utility>

#include <fmt/format.h>

namespace ioport::daemon {
namespace {

constexpr std::string_view online_text = "online";
constexpr std::string_view offline_text = "offline";
// Of a string from the broker, this much reaches a log line (escaped).
constexpr std::size_t shown_bytes = 64;

std::string shown(std::string_view text) {
    return printable(text, shown_bytes);
}

std::span<const std::uint8_t> bytes(std::string_view text) {
    return {reinterpret_cast<const std::uint8_t*>(text.data()), text.size()};
}

std::optional<ModuleType> type_of(const std::optional<ModuleAddress>& module) {
    return module ? std::optional(module->type) : std::nullopt;
}

}  // namespace

Result<std::shared_ptr<MqttJsonSession>> MqttJsonSession::create(
    const asio::any_io_executor& executor, const config::MqttJsonSettings& settings, Log& log,
    EventBus& bus) {
    std::shared_ptr<MqttJsonSession> output(new MqttJsonSession(executor, settings, log, bus));
    std::weak_ptr<MqttJsonSession> weak = output;
    auto client = MqttClient::create(
        executor, settings.connection, {.maximum_packet_size = mqtt_json_maximum_packet_size},
        "mqtt_json", log,
        {.connecting =
             [weak] {
                 if (auto self = weak.lock()) self->connecting();
             },
         .connected =
             [weak] {
                 if (auto self = weak.lock()) self->connected();
             },
         .disconnected = [](const std::string&) {},
         .message =
             [weak](std::string_view topic, std::span<const std::uint8_t> payload, bool retained) {
                 if (auto self = weak.lock()) self->message(topic, payload, retained);
             },
         .subscribed = [](int) {},
         .too_large =
             [weak](std::string_view topic, std::uint64_t bytes) {
                 if (auto self = weak.lock()) self->too_large(topic, bytes);
             }});
    if (!client) return Unexpected(client.error());
    output->client_ = std::move(*client);
    return output;
}

MqttJsonSession::MqttJsonSession(const asio::any_io_executor& executor,
                                 config::MqttJsonSettings settings, Log& log, EventBus& bus)
    : executor_(executor),
      settings_(std::move(settings)),
      node_{settings_.discovery_prefix, settings_.topic_prefix, IOPORTD_VERSION},
      status_topic_(mqtt_json::status_topic(settings_.topic_prefix)),
      log_(log),
      bus_(bus),
      ticker_(executor),
      birth_timer_(executor) {}

void MqttJsonSession::start(const Links& links) {
    build(links);
    log_.info({}, "MQTT JSON output {} on {}{}", settings_.topic_prefix, client_->broker(),
              settings_.discovery
                  ? fmt::format(", Home Assistant discovery under {}", settings_.discovery_prefix)
                  : std::string());
    client_->start();
    tick();
}

void MqttJsonSession::build(const Links& links) {
    links_ = links;
    modules_.clear();
    modules_of_.clear();
    config_topics_.clear();
    connectivity_.clear();
    if (settings_.discovery) config_topics_.insert(mqtt_json::gateway_discovery(node_).topic);
    const auto& prefix = settings_.topic_prefix;
    for (const auto& link : links) {
        const auto& name = link->config().name;
        if (settings_.discovery)
            config_topics_.insert(mqtt_json::link_discovery(node_, name).topic);
        const auto first = modules_.size();
        for (const auto& view : link->modules()) {
            Module module{link,
                          view.slot,
                          view.address,
                          gateway::module_id(view.address),
                          mqtt_json::module_topic(prefix, name, view.address, "state"),
                          mqtt_json::module_topic(prefix, name, view.address, "availability")};
            if (settings_.discovery) {
                module.discovery =
                    mqtt_json::module_discovery(node_, name, view.address, *view.tags);
                for (const auto& config : module.discovery)
                    config_topics_.insert(config.topic);
            }
            modules_.push_back(std::move(module));
        }
        modules_of_[link.get()] = {first, modules_.size()};
    }
    watch_links();
}

void MqttJsonSession::watch_links() {
    const std::weak_ptr<MqttJsonSession> weak = shared_from_this();
    subscription_ = watch_module_data(bus_, links_, [weak](const LinkScheduler* link, int slot) {
        if (auto self = weak.lock()) self->changed(link, slot);
    });
}

void MqttJsonSession::set_links(const Links& links) {
    const auto before = config_topics_;
    build(links);
    // A module that left, or an entity whose object id changed: its config goes (retained,
    // empty), so that Home Assistant removes the entity instead of showing it unavailable.
    std::size_t cleared = 0;
    for (const auto& topic : before)
        if (!config_topics_.contains(topic) && publish(topic, {}, 1, true)) ++cleared;
    stats_.discovery_cleared += cleared;
    if (cleared > 0) log_.info({}, "MQTT JSON: {} discovery config(s) cleared", cleared);
    if (!client_->connected()) return;
    publish_discovery();
    publish_bridge_info();
    for (auto& module : modules_)
        update(module);
    for (const auto& link : links_)
        update_connectivity(*link);
}

void MqttJsonSession::stop(std::chrono::milliseconds deadline, std::function<void()> done) {
    stopping_ = true;
    ticker_.cancel();
    birth_timer_.cancel();
    subscription_.reset();
    // The will is for an unexpected end; a clean one says so itself.
    if (client_->connected())
        publish(status_topic_, offline_text, 1, true, MqttClient::Bound::none);
    client_->stop(deadline, std::move(done));
}

MqttJsonStats MqttJsonSession::stats() const {
    auto stats = stats_;
    stats.connected = client_->connected();
    stats.published = client_->published();
    stats.dropped = client_->dropped();
    return stats;
}

void MqttJsonSession::connecting() {
    if (auto will = client_->set_will(status_topic_, bytes(offline_text), 1, true); !will)
        log_.error({}, "MQTT JSON: {}: a lost connection will not show as {} offline",
                   will.error().message, status_topic_);
}

void MqttJsonSession::connected() {
    subscribe(mqtt_json::set_subscription(settings_.topic_prefix), "sets");
    subscribe(mqtt_json::bridge_request_subscription(settings_.topic_prefix), "bridge requests");
    if (settings_.discovery) {
        subscribe(settings_.discovery_prefix + "/status", "Home Assistant's birth messages");
        // This node's configs, retained ones included: those of modules no longer configured
        // (from before a restart) are cleared when they arrive.
        subscribe(fmt::format("{}/+/{}/+/config", settings_.discovery_prefix,
                              mqtt_json::node_id(settings_.topic_prefix)),
                  "this node's discovery configs");
    }
    publish(status_topic_, online_text, 1, true);
    discovery_due_ = settings_.discovery;
    publish_discovery();
    publish_bridge_info();
    publish_states_again();
}

// Every module's availability and state, and every link's connectivity, as if never sent.
void MqttJsonSession::publish_states_again() {
    for (auto& module : modules_) {
        module.online.reset();
        module.values.clear();
        module.state_due = true;
        update(module);
    }
    connectivity_.clear();
    for (const auto& link : links_)
        update_connectivity(*link);
}

void MqttJsonSession::publish_bridge_info() {
    if (stopping_) return;
    std::vector<mqtt_json::BridgeLink> links;
    for (const auto& link : links_) {
        const auto& config = link->config();
        mqtt_json::BridgeLink info{
            config.name, std::string(config::protocol_name(config.protocol)), config.unit_id, {}};
        for (const auto& module : link->modules())
            info.modules.push_back({gateway::module_id(module.address),
                                    module.address ? std::string(ioport::name(module.address->type))
                                                   : std::string("id2"),
                                    module.address ? module.tags->name : module.name,
                                    std::string(status_text(module.status()))});
        links.push_back(std::move(info));
    }
    publish(mqtt_json::bridge_topic(settings_.topic_prefix, "info"),
            mqtt_json::bridge_info_json(IOPORTD_VERSION, links, settings_.discovery, read_only_), 1,
            true);
}

void MqttJsonSession::update_connectivity(const LinkScheduler& link) {
    if (!settings_.discovery) return;
    const bool ok = link_problems(link).empty();
    const auto last = connectivity_.find(&link);
    if (last != connectivity_.end() && last->second == ok) return;
    const auto topic = mqtt_json::bridge_topic(settings_.topic_prefix,
                                               fmt::format("connectivity/{}", link.config().name));
    if (publish(topic, ok ? "ON" : "OFF", 1, true)) connectivity_[&link] = ok;
}

void MqttJsonSession::subscribe(const std::string& topic, std::string_view what) {
    if (auto subscribed = client_->subscribe(topic, 1); !subscribed)
        log_.error({}, "MQTT JSON: {}: {} will not arrive in this session",
                   subscribed.error().message, what);
}

void MqttJsonSession::publish_discovery() {
    if (!settings_.discovery || stopping_) return;
    const auto gateway = mqtt_json::gateway_discovery(node_);
    discovery_due_ = !publish(gateway.topic, gateway.payload, 1, true);
    for (const auto& link : links_) {
        const auto config = mqtt_json::link_discovery(node_, link->config().name);
        if (!publish(config.topic, config.payload, 1, true)) discovery_due_ = true;
    }
    for (const auto& module : modules_)
        for (const auto& config : module.discovery)
            if (!publish(config.topic, config.payload, 1, true)) discovery_due_ = true;
}

bool MqttJsonSession::publish(const std::string& topic, std::string_view payload, int qos,
                              bool retain, MqttClient::Bound bound) {
    return client_->publish(topic, bytes(payload), qos, retain, bound);
}

void MqttJsonSession::changed(const LinkScheduler* link, int slot) {
    if (stopping_ || !client_->connected()) return;
    const auto of_link = modules_of_.find(link);
    if (of_link != modules_of_.end())
        for (auto i = of_link->second.first; i < of_link->second.second; ++i)
            if (slot < 0 || modules_[i].slot == slot) update(modules_[i]);
    update_connectivity(*link);
}

void MqttJsonSession::update(Module& module) {
    const auto* view = module.link->module_at(module.slot);
    if (view == nullptr) return;
    const bool online = view->status() == gateway::ModuleStatus::online;
    if (module.online != online &&
        publish(module.availability_topic, online ? online_text : offline_text, 1, true)) {
        module.online = online;
        info_due_ = true;  // its status there too, on the next tick: at most once a second
    }
    // Offline: the last document stays, marked unavailable; the next one comes with fresh values.
    if (!online) return;
    const auto type = type_of(module.address);
    const auto& now = view->values;
    const bool moved =
        module.state_due || module.values.size() != now.size() ||
        !gateway::changed_points(type, module.values, now, settings_.deadband).empty();
    if (!moved) return;
    module.state_due = !publish(module.state_topic, mqtt_json::state_json(type, now), 0, true);
    if (!module.state_due) module.values = now;
}

void MqttJsonSession::tick() {
    ticker_.expires_after(std::chrono::seconds(1));
    ticker_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        auto self = weak.lock();
        if (ec || !self || self->stopping_) return;
        if (self->client_->connected()) {
            if (self->discovery_due_) self->publish_discovery();
            if (std::exchange(self->info_due_, false)) self->publish_bridge_info();
            for (auto& module : self->modules_)
                if (module.state_due || !module.online) self->update(module);
        }
        self->tick();
    });
}

void MqttJsonSession::message(std::string_view topic, std::span<const std::uint8_t> payload,
                              bool retained) {
    const std::string_view text(reinterpret_cast<const char*>(payload.data()), payload.size());
    if (auto set_topic = mqtt_json::parse_set_topic(settings_.topic_prefix, topic)) {
        // Empty: a retained set being cleared from the broker, not a command.
        if (!text.empty()) set(*set_topic, text, retained);
        return;
    }
    if (auto name = mqtt_json::parse_bridge_request(settings_.topic_prefix, topic)) {
        if (!text.empty() || !retained) request(*name, text, retained);
        return;
    }
    if (!settings_.discovery) return;
    if (topic == settings_.discovery_prefix + "/status") {
        if (text == online_text) home_assistant_online();
        return;
    }
    // One of this node's configs (the subscription's pattern): an empty one is a deletion.
    if (!text.empty() && !config_topics_.contains(std::string(topic))) stale_config(topic);
}

void MqttJsonSession::too_large(std::string_view topic, std::uint64_t bytes) {
    const auto size = fmt::format("{} bytes, more than the {} a message to this gateway may have",
                                  bytes, mqtt_json_maximum_packet_size);
    if (auto set_topic = mqtt_json::parse_set_topic(settings_.topic_prefix, topic)) {
        ++stats_.sets;
        refuse("too large", {},
               fmt::format("MQTT JSON: set {}/{}/{} refused unread: {}", shown(set_topic->link),
                           shown(set_topic->module), shown(set_topic->point), size));
        return;
    }
    if (const auto held = refusals_.admit("too large", std::chrono::steady_clock::now()))
        log_.warn({}, "MQTT JSON: a message on {} refused unread: {} (logged once a minute){}",
                  shown(topic), size, held_back(*held));
}

// A config under this node that it does not publish now: a module removed while the gateway
// was not running, or an entity renamed. Cleared, as gateway.md §6.3 says.
void MqttJsonSession::stale_config(std::string_view topic) {
    if (!publish(std::string(topic), {}, 1, true)) return;
    ++stats_.discovery_cleared;
    if (const auto held = refusals_.admit("stale config", std::chrono::steady_clock::now()))
        log_.info({}, "MQTT JSON: discovery config {} cleared: no such module is configured{}",
                  shown(topic), held_back(*held));
}

// Home Assistant came (back) online: it asks integrations to send their configs again. Anyone
// on the broker can say so, as often as they like: served at once, then at most once every
// home_assistant_birth_interval, the births in between by one republication when it ends.
void MqttJsonSession::home_assistant_online() {
    const auto now = std::chrono::steady_clock::now();
    if (births_.asked(now)) {
        serve_home_assistant();
        return;
    }
    if (const auto held = refusals_.admit("home assistant birth", now))
        log_.info({},
                  "MQTT JSON: Home Assistant's birth on {}/status served at most once every {} s; "
                  "the next republication when they are over (logged once a minute){}",
                  settings_.discovery_prefix, home_assistant_birth_interval.count(),
                  held_back(*held));
    wait_for_held_birth();
}

// The timer for a held-back birth, when one waits and none is set.
void MqttJsonSession::wait_for_held_birth() {
    const auto due = births_.due_at();
    if (!due || std::exchange(birth_timer_armed_, true)) return;
    birth_timer_.expires_at(*due);
    birth_timer_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        auto self = weak.lock();
        if (!self) return;
        self->birth_timer_armed_ = false;
        if (ec || self->stopping_) return;
        if (self->births_.due(std::chrono::steady_clock::now())) {
            // Not connected: the next session's start publishes everything anyway.
            if (self->client_->connected()) self->serve_home_assistant();
            return;
        }
        // A birth served at once while this timer was late moved the time on; one held back
        // after it waits for the new time.
        self->wait_for_held_birth();
    });
}

void MqttJsonSession::serve_home_assistant() {
    // The gateway's status as well: on a cluster whose retained messages stay on the node they
    // were published to (ejabberd), a Home Assistant on another node has never seen it, and
    // every entity, whose availability includes it, stays unavailable.
    publish(status_topic_, online_text, 1, true);
    // The configs are retained, but a broker restarted without persistence has lost them too.
    publish_discovery();
    // A Home Assistant restarted on a broker that keeps no retained messages has no state until
    // a value changes, and shows "unknown" meanwhile: give it every one now.
    publish_states_again();
}

// A bridge request (gateway.md §7.3). What comes from the broker reaches the log escaped; a
// client asking too often is answered no more this second.
void MqttJsonSession::request(const std::string& name, std::string_view payload, bool retained) {
    ++stats_.requests;
    const auto now = std::chrono::steady_clock::now();
    if (now - requests_second_ >= std::chrono::seconds(1)) {
        requests_second_ = now;
        requests_in_second_ = 0;
    }
    if (++requests_in_second_ > max_bridge_requests_per_second) {
        ++stats_.requests_dropped;
        if (const auto held = refusals_.admit("bridge requests", now))
            log_.warn({},
                      "MQTT JSON: bridge request {} dropped: more than {} a second (logged "
                      "once a minute){}",
                      shown(name), max_bridge_requests_per_second, held_back(*held));
        return;
    }
    auto parsed = mqtt_json::parse_bridge_request_payload(payload);
    std::string data = "{}";
    if (retained && parsed.error.empty())
        parsed.error =
            "a retained request is not served: it would act at every connect; "
            "publish requests without the retain flag";
    if (!parsed.error.empty()) {
    } else if (name == "health_check") {
        std::vector<std::pair<std::string, std::string>> links;
        for (const auto& link : links_) {
            auto problems = link_problems(*link);
            links.emplace_back(link->config().name, problems.empty() ? "ok" : std::move(problems));
        }
        data = mqtt_json::health_json(links);
    } else if (name == "info") {
        publish_bridge_info();
    } else {
        parsed.error = fmt::format("'{}' is not a request here: health_check or info", shown(name));
    }
    publish(mqtt_json::bridge_topic(settings_.topic_prefix, "response/" + name),
            mqtt_json::bridge_response_json(data, parsed.error, parsed.transaction), 0, false);
}

void MqttJsonSession::refuse(std::string_view key, const LogFields& fields, std::string text) {
    ++stats_.sets_refused;
    const auto held = refusals_.admit(key, std::chrono::steady_clock::now());
    if (!held) return;
    text += held_back(*held);
    log_.warn(fields, "{} (logged once a minute per module and reason)", text);
    bus_.publish(
        Note{.kind = EventKind::write, .link = fields.link, .client = "mqtt_json", .text = text});
}

void MqttJsonSession::set(const mqtt_json::SetTopic& topic, std::string_view payload,
                          bool retained) {
    ++stats_.sets;
    const auto address =
        fmt::format("{}/{}/{}", shown(topic.link), shown(topic.module), shown(topic.point));
    const auto value = shown(payload);
    const auto module = std::ranges::find_if(modules_, [&](const Module& m) {
        return m.id == topic.module && m.link->config().name == topic.link;
    });
    if (module == modules_.end()) {
        refuse("unknown module", {},
               fmt::format("MQTT JSON: set {} = {} refused: no such link and module here", address,
                           value));
        return;
    }
    const auto& link = module->link;
    const LogFields fields{link->config().name, link->config().unit_id, {}, "mqtt_json"};
    const auto refuse_set = [&](std::string_view reason, const std::string& why) {
        refuse(fmt::format("{}/{} {}", topic.link, topic.module, reason), fields,
               fmt::format("MQTT JSON: set {} = {} refused: {}", address, value, why));
    };
    if (retained) {
        refuse_set("retained",
                   "it is a retained message: a command left on the broker would "
                   "act at every connect; publish sets without the retain flag");
        return;
    }
    if (read_only_) {
        refuse_set("read_only", "modbus.read_only is set: nothing is written on a client's behalf");
        return;
    }
    auto plan = gateway::plan_text_write(module->address, topic.point, payload);
    if (!plan) {
        refuse_set("payload", printable(plan.error().message, 4 * shown_bytes));
        return;
    }
    WriteOrigin origin{.client = "mqtt_json",
                       .function = "set",
                       .address = address,
                       .value = value,
                       .request = fmt::format("set {} = {}", address, value)};
    asio::co_spawn(
        executor_,
        [self = shared_from_this(), link, plan = std::move(*plan), origin = std::move(origin),
         key = fmt::format("{}/{} busy", topic.link,
                           topic.module)]() mutable -> asio::awaitable<void> {
            const auto what = origin.request;
            const auto result = co_await link->write(std::move(plan), std::move(origin));
            if (result != WriteResult::busy) co_return;  // audited by the link
            self->refuse(key, {link->config().name, link->config().unit_id, {}, "mqtt_json"},
                         fmt::format("MQTT JSON: {} refused: {} writes are waiting for link {} "
                                     "(max_pending_writes)",
                                     what, link->config().max_pending_writes, link->config().name));
        },
        asio::detached);
}

}  // namespace ioport::daemon
