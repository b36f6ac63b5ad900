// The Sparkplug B 3.0 edge node (gateway.md §5.5): this box as one edge node of a plant-wide
// MQTT namespace, one Sparkplug device per configured module.
//
// Report by exception, driven by the links: each link tells the node at once when a module's
// status or values may have changed (LinkScheduler::subscribe); the node compares with what
// it last published and sends DDATA with the metrics that changed (an analog channel's raw word
// and value together, only beyond `deadband`), DDEATH when a module goes offline and DBIRTH,
// with fresh values, when it is back.
// Nothing here waits on the broker: publication goes through MqttClient's bounded queue, and
// what it drops makes the node rebirth once there is room again, so a host never keeps a value
// that was lost.
//
// A session: CONNECT with NDEATH as the will, carrying bdSeq (one more for every CONNECT), in
// MQTT 5 with Clean Start, a Session Expiry Interval of 0 and a Maximum Packet Size, so that a
// command too large for any host never reaches this process (Sparkplug 3.0 allows MQTT 5); in
// 3.1.1 with Clean Session to a broker that refuses 5, whose message_size_limit is then the only
// bound (docs/sparkplug.md);
// NBIRTH (seq 0) with the node metrics, then a DBIRTH per module that is online; from then on
// seq counts every message 0..255. With primary_host_id the births wait for that host's STATE
// {"online": true}; an offline STATE ends the session (NDEATH, DISCONNECT, a new CONNECT), and
// the next one begins when the host is back. NCMD "Node Control/Rebirth"
// sends every birth again with the same bdSeq, at most once a second (requests in between are
// served by one rebirth at the end of that second). DCMD writes take the gateway's one write path
// (sparkplug::plan_command, then LinkScheduler::write): validated, confirmed by the device,
// counted and audited by the link like a Modbus write; the new value is published when the device
// confirmed it, not before. With modbus.read_only nothing is written; a DCMD naming more metrics
// than the device has writable ones is refused whole, before it is decoded. A clean stop publishes
// NDEATH, then disconnects; in MQTT 5 its DISCONNECT asks the broker for the will too, as
// Sparkplug 3.0 requires, so a host sees the end twice with the same bdSeq.
//
// Store-and-forward (gateway.md §6.2, with mqtt.store): while no session can publish, what would
// have gone out as DDATA goes to the store (SparkplugStore) with its acquisition time; after the
// next births it is forwarded oldest first, is_historical, at most forward_rate a second beside
// the live data. After each batch the node repeats its NCMD SUBSCRIBE: the SUBACK proves the
// broker read the batch, and only then are its records deleted. Live DDATA is QoS 0: each is
// kept (UnprovenData) until a SUBACK proves the broker read it, one SUBSCRIBE in flight at a time
// and at most one every live_proof_interval while live DDATA flows; what a lost connection leaves
// unproven goes to the store, so that a broker that stopped reading (a clean stop) loses none of
// it. Several brokers: MqttClient walks the list on every loss; with primary_host_id, a broker
// where that host is offline (or sends no STATE within keepalive), or an NCMD Node Control/Next
// Server, makes the node say NDEATH and walk.
//
// Templates (gateway.md §7.2, mqtt.templates): NBIRTH defines a template per module type
// configured (_types_/<type>); each DBIRTH is one instance of its type with every member, each
// DDATA the instance with the members that changed; the store keeps records flat, by name, and
// they are forwarded as instances; a DCMD instance is a write of its members, flat names too.
//
// Everything from the broker is hostile: its strings reach the log escaped (printable), and the
// lines a host can cause at any rate (refused commands) go through one LogLimiter.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "config/gateway_config.hpp"
#include "daemon/base/log.hpp"
#include "daemon/core/events.hpp"
#include "daemon/core/link_scheduler.hpp"
#include "daemon/mqtt/mqtt_client.hpp"
#include "daemon/sparkplug/store.hpp"
#include "daemon/sparkplug/unproven.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::daemon {

// Link counters go out in NDATA at most this often: they change with every transaction.
inline constexpr std::chrono::seconds counter_period{10};
// NCMD rebirth requests closer than this are served once (gateway.md §5.5).
inline constexpr std::chrono::seconds min_rebirth_interval{1};
// An NCMD may name the Node Control metrics of Sparkplug 3.0 (Rebirth, Reboot, Next Server, Scan
// rate) together; only Rebirth acts. More is refused whole, like an oversized DCMD.
inline constexpr std::size_t node_command_metrics = 4;
// The largest packet the broker may send this node (MQTT 5's Maximum Packet Size): what arrives
// is a DCMD (18 KiB at most, sparkplug::decode_command), an NCMD or a STATE (1 KiB); a 64 MiB
// DCMD once took the daemon from 15 to 146 MB before it was refused.
inline constexpr std::uint32_t sparkplug_maximum_packet_size = 64 << 10;
// With a store, live DDATA that went out is proven read by the broker (a SUBSCRIBE's SUBACK) at
// most this long after it, plus the round trip: what a lost connection leaves unproven is stored
// and may arrive twice, so this bounds those duplicates; a SUBSCRIBE this often while data flows
// is what it costs the broker (docs/sparkplug.md).
inline constexpr std::chrono::milliseconds live_proof_interval{100};
// A STATE whose timestamp is further ahead of this node's clock than this does not order the
// STATEs after it (docs/sparkplug.md: clocks set by NTP agree to milliseconds; a forged
// timestamp must not make the host's real offline look stale).
inline constexpr std::chrono::seconds state_clock_tolerance{10};

struct SparkplugStats {
    bool connected = false;                          // to the broker
    bool online = false;                             // births sent in this session
    bool forwarding = false;                         // the store's backlog is going out
    std::optional<StoreStats> store;                 // nullopt: no store
    std::optional<std::uint64_t> backlog_oldest_ms;  // acquisition time of the oldest stored
    std::uint64_t bdseq = 0;
    std::uint64_t published = 0;
    std::uint64_t dropped = 0;
    std::uint64_t births = 0;    // NBIRTHs, rebirths included
    std::uint64_t commands = 0;  // DCMD metrics; a DCMD refused whole counts as one
    std::uint64_t commands_refused = 0;
    std::uint64_t commands_unknown_device = 0;  // a DCMD to a device this node does not have
    struct {
        std::uint64_t taken = 0;    // acted on, its timestamp the new mark
        std::uint64_t ahead = 0;    // beyond state_clock_tolerance: acted on, not the mark
        std::uint64_t stale = 0;    // older than the mark: ignored
        std::uint64_t refused = 0;  // too large, or not a STATE
    } states;                       // of the primary host
};

class SparkplugNode : public std::enable_shared_from_this<SparkplugNode> {
  public:
    // `next_bdseq`: of the first CONNECT; a node that replaces another (a reload that changed
    // the MQTT settings) goes on from the old one's, as bdSeq counts every CONNECT sent. None: the
    // process's first node, which goes on from what its store kept (0 without one).
    // Fails when the store's directory is refused (store.hpp). `disk`: the daemon's disk thread,
    // for the store.
    static Result<std::shared_ptr<SparkplugNode>> create(
        const asio::any_io_executor& executor, const config::MqttSettings& settings, Log& log,
        EventBus& bus, WorkerThread& disk, std::optional<std::uint64_t> next_bdseq = {});
    ~SparkplugNode() = default;
    SparkplugNode(const SparkplugNode&) = delete;
    SparkplugNode& operator=(const SparkplugNode&) = delete;

    void start(const Links& links);
    // A reload: the links running now. A changed module map is announced with new births; the
    // same map keeps the session (restarted links are only watched anew).
    void set_links(const Links& links);
    // modbus.read_only: DCMD writes are refused, as Modbus writes are.
    void set_read_only(bool read_only) { read_only_ = read_only; }
    // NDEATH, then DISCONNECT; `done` when sent or after `deadline`.
    void stop(std::chrono::milliseconds deadline, std::function<void()> done);

    const config::MqttSettings& settings() const { return settings_; }
    SparkplugStats stats() const;
    std::uint64_t next_bdseq() const { return next_bdseq_; }
    std::string broker() const { return client_->broker(); }

  private:
    struct Device {
        std::shared_ptr<LinkScheduler> link;
        int slot = 0;
        std::optional<ModuleAddress> module;  // nullopt: the ID-2
        std::string id;
        std::vector<sparkplug::MetricSpec> metrics;
        std::uint64_t first_alias = 0;
        // As the last births said them: a reload that changes them rebirths (gateway.md §6.1).
        gateway::ModuleTags tags{};
        std::vector<std::vector<sparkplug::Property>> properties{};
        bool born = false;  // DBIRTH sent, no DDEATH since, in this session
        std::vector<std::optional<gateway::PointValue>> published{};
        // The module's first values in this process, read while no session could take them:
        // not stored, as its DBIRTH will carry them, unless they change before it does.
        std::optional<sparkplug::Payload> first_unstored{};
    };
    struct LinkMetrics {
        std::string name;
        bool up = false;
        std::uint64_t ok = 0;
        std::uint64_t failed = 0;
        std::uint64_t reopens = 0;
    };

    SparkplugNode(const asio::any_io_executor& executor, config::MqttSettings settings, Log& log,
                  EventBus& bus);
    void build(const Links& links);
    void watch_links();
    void connecting();
    void connected();
    std::optional<int> subscribe(const std::string& topic, std::string_view what);
    void disconnected();
    void message(std::string_view topic, std::span<const std::uint8_t> payload);
    // A message larger than sparkplug_maximum_packet_size, refused unread (MQTT 3.1.1).
    void too_large(std::string_view topic, std::uint64_t bytes);
    void host_state(std::span<const std::uint8_t> payload);
    void node_command(std::span<const std::uint8_t> payload);
    void rebirth_asked();
    void command(const sparkplug::Topic& topic, std::span<const std::uint8_t> payload);
    void device_command(Device& device, const sparkplug::Metric& metric);
    // One point of a DCMD (a flat metric, or a member of the device's instance: `instance`).
    void point_command(Device& device, const sparkplug::Metric& metric, bool instance);
    // The definitions of the module types configured, for NBIRTH (gateway.md §7.2).
    void definitions(sparkplug::Payload& nbirth, std::uint64_t now) const;
    void refuse(std::string_view key, const LogFields& fields, std::string text);
    void birth();
    void device_birth(Device& device, const ModuleState& view);
    void changed(const LinkScheduler* link, int slot);
    // A device's metrics that changed since they were last published or kept, as a DDATA
    // payload without seq: by alias in a session, by name for the store (aliases belong to a
    // session).
    enum class MetricsBy { alias, name };
    struct Changes {
        // every metric's point, now: the module's values in the link, for this call only
        std::span<const std::optional<gateway::PointValue>> values;
        std::vector<std::size_t> changed;  // indexes into values
        sparkplug::Payload payload;
    };
    Changes changes(Device& device, const ModuleState& view, MetricsBy by) const;
    static void published(Device& device, const Changes& data);
    void update(Device& device);
    void keep(Device& device);
    void store_ready();
    void start_forwarding();
    void forward_tick();
    void forward(std::uint64_t session, std::vector<StoredRecord> records);
    static void by_alias(const Device& device, sparkplug::Metric& metric);
    // A live DDATA went out: unproven until a round trip after it.
    void sent_live(const Device& device, const Changes& data);
    void prove_live();
    void send_live_proof();
    // The connection is lost: the live DDATA not proven go to the store, in order.
    void keep_unproven();
    void subscribed(int mid);
    void walk(const std::string& why);
    void link_data(bool counters);
    void tick();
    bool publish(sparkplug::MessageType type, std::string_view device,
                 const sparkplug::Payload& payload, int qos = 0);
    std::uint64_t next_seq();
    std::vector<std::uint8_t> death_payload() const;
    void publish_death();
    LinkMetrics link_metrics(const LinkScheduler& link) const;

    asio::any_io_executor executor_;
    config::MqttSettings settings_;
    Log& log_;
    EventBus& bus_;
    std::shared_ptr<MqttClient> client_;
    asio::steady_timer ticker_;
    asio::steady_timer rebirth_timer_;
    EventBus::Subscription subscription_;
    LogLimiter refusals_;
    std::vector<Device> devices_;
    // Each link's devices, [first, last) in devices_: a change looks at its own link's devices
    // only, so that its cost does not grow with the number of links (issue 42).
    std::map<const LinkScheduler*, std::pair<std::size_t, std::size_t>> devices_of_;
    std::vector<LinkMetrics> links_published_;
    Links links_;
    std::uint64_t next_bdseq_ = 0;
    bool bdseq_spent_ = true;  // the last CONNECT went out: the next takes a new bdSeq
    std::uint64_t bdseq_ = 0;
    std::uint64_t seq_ = 0;
    bool host_online_ = true;                 // always, without primary_host_id
    std::uint64_t host_state_timestamp_ = 0;  // of the last STATE taken: older ones are stale
    bool born_ = false;
    // The message id of the session's last SUBSCRIBE: the births wait for its SUBACK, which
    // proves the broker took the subscriptions (a broker may close the connection at one
    // instead, as RabbitMQ does when the queue's node is down).
    std::optional<int> births_await_suback_;
    bool rebirth_due_ = false;  // a message was dropped: the host's view is incomplete
    bool stopping_ = false;
    bool read_only_ = false;
    bool rebirth_waiting_ = false;  // a rebirth request waits for min_rebirth_interval to pass
    std::chrono::steady_clock::time_point counters_sent_{};
    std::optional<std::chrono::steady_clock::time_point> last_nbirth_;
    SparkplugStats stats_;

    // Store-and-forward (gateway.md §6.2).
    struct Proof {
        std::uint64_t through = 0;  // the last record forwarded before the SUBSCRIBE
        std::uint64_t records = 0;  // forwarded since the previous proof
    };
    std::shared_ptr<SparkplugStore> store_;
    asio::steady_timer forward_timer_;
    std::uint64_t session_ = 0;       // one more for every connection
    std::uint64_t forward_sent_ = 0;  // the last record published in this session
    bool forward_reading_ = false;
    std::map<int, Proof> proofs_;  // by SUBSCRIBE message id
    std::optional<std::uint64_t> backlog_oldest_ms_;
    std::optional<std::chrono::steady_clock::time_point> forward_started_;
    std::uint64_t forwarded_in_run_ = 0;
    // Live DDATA not yet proven read by the broker, with a store only.
    UnprovenData unproven_;
    std::map<int, std::uint64_t> live_proofs_;  // by SUBSCRIBE message id: UnprovenData::mark()
    asio::steady_timer proof_timer_;
    bool proof_timer_armed_ = false;
    std::uint64_t forgotten_logged_ = 0;  // UnprovenData::forgotten() in the last log line
    // Several brokers and a primary host: its STATE must come within keepalive.
    asio::steady_timer host_timer_;
};

}  // namespace ioport::daemon
