// Plain MQTT with JSON and Home Assistant discovery (gateway.md §6.3): the model as retained
// JSON documents a Node-RED flow, Telegraf or Home Assistant reads without a register map, on a
// connection of its own that may run beside the Sparkplug node's.
//
// Report by exception, like the Sparkplug node: each link tells the output when a module's
// status or values may have changed; the output publishes the module's `availability` when its
// status moved and its whole `state` document when a value moved (an analog channel beyond
// `deadband`). A publish the client's bounded queue drops leaves the module due, and the next
// tick (once a second) sends its current document: what the broker keeps converges on the
// model, never on a value that was skipped.
//
// A session: CONNECT with `<prefix>/status` = offline as the retained will; then `online`, the
// discovery configs, every module's availability and state, and the subscriptions (sets; with
// discovery, Home Assistant's birth and this node's own configs, so that configs of modules no
// longer configured are cleared even after a restart). A clean stop publishes `offline` itself.
//
// Writes: `<prefix>/<link>/<module>/<point>/set` takes the gateway's one write path
// (gateway::plan_text_write, then LinkScheduler::write): validated, confirmed by the device,
// audited with CLIENT=mqtt_json; the state shows the value once the device confirmed it.
// Refused: a retained set (a command left on the broker must not act at every connect), any set
// under modbus.read_only, a module or point that is not there, a payload plan_text_write does not
// take. What comes from the broker reaches the log escaped, and refusals go through one
// LogLimiter.
//
// The bridge topics (gateway.md §7.3, as zigbee2mqtt has them): `<prefix>/bridge/info` retained
// at every connection and reload, and at the next tick after a module's status changed; requests on
// `<prefix>/bridge/request/<name>` (health_check, info) answered on `bridge/response/<name>` with
// the transaction echoed, at most max_bridge_requests_per_second (more are dropped, counted and
// logged once a minute); with discovery, a connectivity sensor per link on
// `bridge/connectivity/<link>`, and Home Assistant's birth makes every module's state and
// availability published again, for a Home Assistant on a broker that keeps no retained messages:
// at once, then at most once every home_assistant_birth_interval, as any client can send one.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/base/log.hpp"
#include "daemon/core/events.hpp"
#include "daemon/core/link_scheduler.hpp"
#include "daemon/mqtt/mqtt_client.hpp"
#include "daemon/mqtt_json/birth_pacer.hpp"
#include "protocol/mqtt_json.hpp"

namespace ioport::daemon {

// Home Assistant's birth is served at once, then at most once this often (gateway.md §7.5):
// births in between are served by one republication when it ends (BirthPacer).
inline constexpr std::chrono::seconds home_assistant_birth_interval{30};
// Bridge requests answered a second; a client asking more often is answered no more.
inline constexpr int max_bridge_requests_per_second = 10;
// The largest packet the broker may send this connection (MQTT 5's Maximum Packet Size): what
// arrives is a set (a word), Home Assistant's birth, or a discovery config of this node's own (a
// few KiB); a 250 MB set once took the daemon past MemoryMax=.
inline constexpr std::uint32_t mqtt_json_maximum_packet_size = 64 << 10;

struct MqttJsonStats {
    bool connected = false;
    std::uint64_t published = 0;
    std::uint64_t dropped = 0;
    std::uint64_t sets = 0;  // set messages received
    std::uint64_t sets_refused = 0;
    std::uint64_t discovery_cleared = 0;  // configs of modules no longer configured
    std::uint64_t requests = 0;           // bridge requests received
    std::uint64_t requests_dropped = 0;   // over max_bridge_requests_per_second
};

class MqttJsonSession : public std::enable_shared_from_this<MqttJsonSession> {
  public:
    static Result<std::shared_ptr<MqttJsonSession>> create(const asio::any_io_executor& executor,
                                                           const config::MqttJsonSettings& settings,
                                                           Log& log, EventBus& bus);
    ~MqttJsonSession() = default;
    MqttJsonSession(const MqttJsonSession&) = delete;
    MqttJsonSession& operator=(const MqttJsonSession&) = delete;

    void start(const Links& links);
    // A reload: the links running now. Discovery configs of modules that left are cleared, those
    // of changed names or units published again.
    void set_links(const Links& links);
    // modbus.read_only: sets are refused, as Modbus writes are.
    void set_read_only(bool read_only) { read_only_ = read_only; }
    // `offline`, then DISCONNECT; `done` when sent or after `deadline`.
    void stop(std::chrono::milliseconds deadline, std::function<void()> done);

    const config::MqttJsonSettings& settings() const { return settings_; }
    MqttJsonStats stats() const;
    std::string broker() const { return client_->broker(); }

  private:
    struct Module {
        std::shared_ptr<LinkScheduler> link;
        int slot = 0;
        std::optional<ModuleAddress> address;  // nullopt: the ID-2
        std::string id;                        // "dim16_0", "id2"
        std::string state_topic;
        std::string availability_topic;
        std::vector<mqtt_json::Discovery> discovery{};
        // As last published in this session; nullopt: not yet.
        std::optional<bool> online{};
        std::vector<std::optional<gateway::PointValue>> values{};  // of the last state document
        bool state_due = true;
    };

    MqttJsonSession(const asio::any_io_executor& executor, config::MqttJsonSettings settings,
                    Log& log, EventBus& bus);
    void build(const Links& links);
    void watch_links();
    void connecting();
    void connected();
    void subscribe(const std::string& topic, std::string_view what);
    void publish_discovery();
    void message(std::string_view topic, std::span<const std::uint8_t> payload, bool retained);
    // A message larger than mqtt_json_maximum_packet_size, refused unread (MQTT 3.1.1).
    void too_large(std::string_view topic, std::uint64_t bytes);
    void stale_config(std::string_view topic);
    void home_assistant_online();
    void wait_for_held_birth();
    // Every discovery config and every module's state and availability, for Home Assistant.
    void serve_home_assistant();
    void set(const mqtt_json::SetTopic& topic, std::string_view payload, bool retained);
    void request(const std::string& name, std::string_view payload, bool retained);
    void publish_bridge_info();
    void publish_states_again();
    void update_connectivity(const LinkScheduler& link);
    void refuse(std::string_view key, const LogFields& fields, std::string text);
    void changed(const LinkScheduler* link, int slot);
    void update(Module& module);
    bool publish(const std::string& topic, std::string_view payload, int qos, bool retain,
                 MqttClient::Bound bound = MqttClient::Bound::queue);
    void tick();

    asio::any_io_executor executor_;
    config::MqttJsonSettings settings_;
    mqtt_json::Node node_;
    std::string status_topic_;
    Log& log_;
    EventBus& bus_;
    std::shared_ptr<MqttClient> client_;
    asio::steady_timer ticker_;
    EventBus::Subscription subscription_;
    LogLimiter refusals_;
    Links links_;
    std::vector<Module> modules_;
    // Each link's modules, [first, last) in modules_: a change looks at its own link's modules
    // only, so that its cost does not grow with the number of links (issue 42).
    std::map<const LinkScheduler*, std::pair<std::size_t, std::size_t>> modules_of_;
    std::set<std::string> config_topics_;  // every discovery config this node publishes now
    bool discovery_due_ = false;           // not (all) published in this session yet
    bool info_due_ = false;                // a module's status changed since bridge/info
    BirthPacer births_{home_assistant_birth_interval};
    asio::steady_timer birth_timer_;  // a held-back birth: served when births_ says it is due
    bool birth_timer_armed_ = false;
    // Of each link, the connectivity last published in this session.
    std::map<const LinkScheduler*, bool> connectivity_;
    // The bridge requests of the running second.
    std::chrono::steady_clock::time_point requests_second_{};
    int requests_in_second_ = 0;
    bool stopping_ = false;
    bool read_only_ = false;
    MqttJsonStats stats_;
};

}  // namespace ioport::daemon
