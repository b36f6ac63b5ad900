#include "daemon/gateway.hpp"

#include <algorithm>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "config/duration.hpp"
#include "daemon/http/render.hpp"

namespace ioport::daemon {

Gateway::Gateway(const asio::any_io_executor& executor, config::GatewayConfig config, Log& log,
                 DiskThread& disk)
    : executor_(executor),
      config_(std::move(config)),
      log_(log),
      disk_(disk),
      recorded_(bus_.subscribe([this](const BusEvent& event) { record(events_, event); })) {}

std::shared_ptr<LinkScheduler> Gateway::make_link(const config::LinkConfig& link) {
    return std::make_shared<LinkScheduler>(executor_, link, log_, bus_);
}

std::shared_ptr<HttpServer> Gateway::make_http(const config::HttpSettings& settings) {
    return std::make_shared<HttpServer>(
        executor_, settings, host_name_, log_,
        [this](const Route& route) { return render_page(view(), route); });
}

GatewayView Gateway::view() const {
    return {config_, links_, *server_, sparkplug_.get(), mqtt_json_.get(), events_, started_};
}

Result<> Gateway::start() {
    for (const auto& link : config_.links)
        links_.push_back(make_link(link));
    // Comm loss reaches the links running then: a reload replaces links_, not this callback.
    server_ = std::make_shared<ModbusServer>(executor_, config_.modbus, links_, log_, bus_, [this] {
        for (auto& link : links_)
            link->enter_safe_state();
    });
    for (auto& link : links_)
        link->start();
    if (auto started = server_->start(); !started) return started;
    log_warnings();
    if (config_.http) {
        http_ = make_http(*config_.http);
        if (auto started = http_->start(); !started) return started;
    }
    if (auto started = start_sparkplug(); !started) return started;
    return start_mqtt_json();
}

void Gateway::log_warnings() {
    for (const auto& warning : config::warnings(config_))
        log_.warn({}, "{}", warning);
}

Result<> Gateway::start_sparkplug(std::uint64_t next_bdseq) {
    if (!config_.mqtt) return {};
    auto node = SparkplugNode::create(executor_, *config_.mqtt, log_, bus_, disk_, next_bdseq);
    if (!node) return Unexpected(node.error());
    sparkplug_ = std::move(*node);
    sparkplug_->set_read_only(config_.modbus.read_only);
    sparkplug_->start(links_);
    return {};
}

Result<> Gateway::start_mqtt_json() {
    if (!config_.mqtt_json) return {};
    auto output = MqttJsonOutput::create(executor_, *config_.mqtt_json, log_, bus_);
    if (!output) return Unexpected(output.error());
    mqtt_json_ = std::move(*output);
    mqtt_json_->set_read_only(config_.modbus.read_only);
    mqtt_json_->start(links_);
    return {};
}

void Gateway::shut_down(std::function<void()> done) {
    // Shared by the links' and the MQTT sessions' callbacks; `done` runs when the last has
    // finished.
    auto remaining =
        std::make_shared<std::size_t>(links_.size() + (sparkplug_ ? 1 : 0) + (mqtt_json_ ? 1 : 0));
    auto finished = [remaining, done = std::move(done)] {
        if (--*remaining == 0) done();
    };
    if (mqtt_json_) mqtt_json_->stop(mqtt_json_stop_deadline, finished);
    if (sparkplug_) sparkplug_->stop(sparkplug_stop_deadline, finished);
    if (http_) http_->stop();
    server_->shut_down();
    for (auto& link : links_)
        link->finish(config_.on_shutdown, finished);
}

void Gateway::stop() {
    if (mqtt_json_) mqtt_json_->stop(std::chrono::milliseconds(0), [] {});
    if (sparkplug_) sparkplug_->stop(std::chrono::milliseconds(0), [] {});
    if (http_) http_->stop();
    if (server_) server_->stop();
    for (auto& link : links_)
        link->stop();
}

Result<std::string> Gateway::reload(config::GatewayConfig next) {
    if (next.mqtt && next.mqtt->store && next.mqtt != config_.mqtt)
        if (auto checked = check_store_directory(next.mqtt->store->path); !checked)
            return Unexpected(checked.error());
    if (auto bound = server_->prepare(next.modbus); !bound) return Unexpected(bound.error());
    if (auto bound = prepare_http(next.http); !bound) return Unexpected(bound.error());
    const bool same_word_order = next.modbus.word_order == config_.modbus.word_order;
    const bool modbus_changed = !(next.modbus == config_.modbus);
    const bool http_changed = next.http != config_.http;
    const bool mqtt_changed = next.mqtt != config_.mqtt;
    const bool mqtt_json_changed = next.mqtt_json != config_.mqtt_json;
    Links links;
    struct {
        std::vector<std::string> kept, retagged, restarted, added, removed;
    } names;
    for (const auto& link : next.links) {
        const auto old = std::find_if(links_.begin(), links_.end(), [&](const auto& running) {
            return running && running->config().name == link.name;
        });
        if (old != links_.end() && same_word_order && (*old)->config() == link) {
            if (!config::same_tags((*old)->config(), link)) {
                (*old)->retag(link);
                names.retagged.push_back(link.name);
            }
            links.push_back(*old);
            names.kept.push_back(link.name);
            old->reset();
            continue;
        }
        (old != links_.end() ? names.restarted : names.added).push_back(link.name);
        links.push_back(nullptr);  // made once the old ones have let go of their ports
    }
    // The links left are changed or gone; they close their ports before a new link opens one,
    // which may be the same device.
    for (auto& link : links_) {
        if (!link) continue;
        if (std::ranges::find(names.restarted, link->config().name) == names.restarted.end())
            names.removed.push_back(link->config().name);
        link->stop();
    }
    config_ = std::move(next);
    for (std::size_t i = 0; i < links.size(); ++i) {
        if (links[i]) continue;
        links[i] = make_link(config_.links[i]);
        links[i]->start();
        // Outputs stay safe until a client writes them (gateway.md §5.3): a link started anew
        // while the clients are still silent starts in its safe state, not at `initial`, and
        // the loss is not declared again before a request comes.
        if (server_->comm_lost()) links[i]->enter_safe_state();
    }
    links_ = std::move(links);
    server_->apply(config_.modbus, links_);
    log_warnings();
    apply_http(config_.http);
    if (mqtt_changed) {
        // Another broker or node: this session ends cleanly (NDEATH), a new one begins.
        const auto next_bdseq = sparkplug_ ? sparkplug_->next_bdseq() : 0;
        if (sparkplug_) sparkplug_->stop(sparkplug_stop_deadline, [] {});
        sparkplug_.reset();
        if (auto started = start_sparkplug(next_bdseq); !started)
            log_.error({}, "SIGHUP: Sparkplug not started: {}", started.error().message);
    } else if (sparkplug_) {
        sparkplug_->set_read_only(config_.modbus.read_only);
        sparkplug_->set_links(links_);
    }
    if (mqtt_json_changed) {
        // Another broker or prefix: this session ends cleanly (offline), a new one begins.
        if (mqtt_json_) mqtt_json_->stop(mqtt_json_stop_deadline, [] {});
        mqtt_json_.reset();
        if (auto started = start_mqtt_json(); !started)
            log_.error({}, "SIGHUP: MQTT JSON output not started: {}", started.error().message);
    } else if (mqtt_json_) {
        mqtt_json_->set_read_only(config_.modbus.read_only);
        mqtt_json_->set_links(links_);
    }
    const auto list = [](const std::vector<std::string>& of) {
        return of.empty() ? std::string("none") : fmt::format("{}", fmt::join(of, " "));
    };
    auto summary = fmt::format(
        "links kept: {}; restarted: {}; added: {}; removed: {}; Modbus settings {}; HTTP {}; "
        "MQTT {}; MQTT JSON {}; names, units or scales changed: {}",
        list(names.kept), list(names.restarted), list(names.added), list(names.removed),
        modbus_changed ? "changed" : "unchanged", http_changed ? "changed" : "unchanged",
        mqtt_changed ? "changed" : "unchanged", mqtt_json_changed ? "changed" : "unchanged",
        list(names.retagged));
    bus_.publish(Note{.kind = EventKind::reload,
                      .text = fmt::format("configuration reloaded: {}", summary)});
    return summary;
}

Result<> Gateway::prepare_http(const std::optional<config::HttpSettings>& next) {
    next_http_.reset();
    if (!next) return {};
    if (http_ && http_->settings().listen_host == next->listen_host &&
        http_->settings().listen_port == next->listen_port)
        return {};
    auto server = make_http(*next);
    if (auto started = server->start(); !started) {
        server->stop();
        return started;
    }
    next_http_ = std::move(server);
    return {};
}

void Gateway::apply_http(const std::optional<config::HttpSettings>& next) {
    if (!next || next_http_) {
        if (http_) {
            http_->stop();
            if (!next) log_.info({}, "HTTP server stopped: no http section any more");
        }
        http_ = std::exchange(next_http_, nullptr);
        return;
    }
    http_->apply(*next);
}

std::optional<asio::ip::tcp::endpoint> Gateway::http_endpoint() const {
    if (!http_) return std::nullopt;
    return http_->local_endpoint();
}

std::string Gateway::summary() const {
    int up = 0;
    int online = 0;
    int configured = 0;
    for (const auto& link : links_) {
        up += link->port_open() ? 1 : 0;
        online += link->modules_online();
        configured += link->config().protocol == config::Protocol::id2
                          ? 1
                          : static_cast<int>(link->config().modules.size());
    }
    return fmt::format("{} of {} links up, {} of {} modules online, {} clients", up, links_.size(),
                       online, configured, server_->connections());
}

bool Gateway::healthy() const {
    const auto now = Clock::now();
    return std::all_of(links_.begin(), links_.end(),
                       [&](const auto& link) { return link->progressing(now); });
}

namespace {

std::string units_of(const modbus_security::Role& role) {
    std::string units;
    for (std::size_t id = 0; id < role.units.size(); ++id)
        if (role.units.test(id)) units += fmt::format("{}{}", units.empty() ? "units " : ", ", id);
    return units;
}

// What a module's configuration names, units and scales, beyond the defaults (gateway.md §6.1).
std::string tags_text(const config::ModuleConfig& module) {
    const auto& tags = module.tags;
    const auto defaults = gateway::default_tags(module.address);
    std::string text;
    if (tags.name != defaults.name) text += fmt::format("           name \"{}\"\n", tags.name);
    for (std::size_t c = 0; c < tags.channels.size(); ++c) {
        const auto& channel = tags.channels[c];
        if (channel == defaults.channels[c]) continue;
        text += fmt::format("           c{}", c);
        if (!channel.name.empty()) text += fmt::format(" \"{}\"", channel.name);
        text += channel.unit.empty() ? " no unit" : fmt::format(" {}", channel.unit);
        if (const auto& s = channel.scale)
            text += fmt::format(", scaled [{}, {}] to [{}, {}]", s->in_lo, s->in_hi, s->out_lo,
                                s->out_hi);
        text += fmt::format(", range {}..{}\n", channel.range[0], channel.range[1]);
    }
    std::vector<std::string> points;
    for (std::size_t k = 0; k < tags.points.size(); ++k)
        if (!tags.points[k].empty()) points.push_back(fmt::format("{} \"{}\"", k, tags.points[k]));
    if (!points.empty())
        text +=
            fmt::format("           {} {}\n", is_output(module.address.type) ? "outputs" : "inputs",
                        fmt::join(points, ", "));
    return text;
}

}  // namespace

std::string check_config_text(const config::GatewayConfig& config) {
    const auto& modbus = config.modbus;
    std::string text = fmt::format(
        "Modbus TCP {}, at most {} clients, idle timeout {}, keepalive {}, {}{}, word order "
        "{}, stale {}\n",
        modbus.plain() ? "on " + config::host_port(modbus.listen_host, modbus.listen_port)
        : modbus.tls && !modbus.listen_given ? "off (modbus.tls is on and modbus.listen not given)"
                                             : "off",
        modbus.max_connections, format_duration(modbus.idle_timeout),
        modbus.keepalive.count() == 0 ? "off" : format_duration(modbus.keepalive),
        modbus.allow.empty() ? "any client"
                             : fmt::format("{} allowed networks", modbus.allow.size()),
        modbus.read_only ? ", read-only" : "",
        modbus.word_order == gateway::WordOrder::big ? "big" : "little",
        modbus.stale == gateway::Stale::exception ? "exception" : "hold");
    if (const auto& tls = modbus.tls) {
        text += fmt::format(
            "Modbus/TCP Security (TLS 1.2/1.3, client certificates of {}{}) on {}, certificate {}, "
            "default role {}, at most {} handshakes at once ({} per address)\n",
            tls->client_ca,
            tls->client_crl.empty() ? std::string()
                                    : fmt::format(", revoked ones in {}", tls->client_crl),
            config::host_port(tls->listen_host, tls->listen_port), tls->certificate,
            tls->default_role.empty() ? "none" : tls->default_role, tls->max_handshakes,
            config::per_address_handshakes);
        for (const auto& [name, role] : tls->roles)
            text +=
                fmt::format("  role {}: {} of {}\n", name, modbus_security::to_string(role.access),
                            role.units.all() ? std::string("every unit") : units_of(role));
    } else {
        text += "Modbus/TCP Security off\n";
    }
    if (const auto& http = config.http)
        text += fmt::format("HTTP (status page, /metrics, /healthz) on {}, {}\n",
                            config::host_port(http->listen_host, http->listen_port),
                            http->allow.empty()
                                ? "any client"
                                : fmt::format("{} allowed networks", http->allow.size()));
    else
        text += "HTTP off\n";
    if (const auto& mqtt = config.mqtt) {
        std::vector<std::string> brokers;
        for (const auto& broker : mqtt->brokers)
            brokers.push_back(config::to_string(broker));
        text += fmt::format("Sparkplug B edge node {}/{} on {}{}\n", mqtt->group_id,
                            mqtt->edge_node_id, fmt::join(brokers, ", then "),
                            mqtt->primary_host_id.empty()
                                ? std::string()
                                : fmt::format(", primary host {}", mqtt->primary_host_id));
        if (const auto& store = mqtt->store)
            text += fmt::format(
                "Sparkplug store in {}, at most {} MiB, forwarded at {} messages/s at most\n",
                store->path, store->max_size >> 20, store->forward_rate);
        else
            text += "Sparkplug store off: what changes while no broker takes it is lost\n";
    } else {
        text += "Sparkplug B off\n";
    }
    if (const auto& json = config.mqtt_json) {
        std::vector<std::string> brokers;
        for (const auto& broker : json->connection.brokers)
            brokers.push_back(config::to_string(broker));
        text += fmt::format(
            "MQTT JSON under {} on {}, {}\n", json->topic_prefix, fmt::join(brokers, ", then "),
            json->discovery
                ? fmt::format("Home Assistant discovery under {}", json->discovery_prefix)
                : std::string("no discovery"));
    } else {
        text += "MQTT JSON off\n";
    }
    text += fmt::format(
        "on shutdown: outputs {}; on communication loss: {}; log level {}\n",
        config.on_shutdown == config::OnShutdown::keep ? "kept as they are" : "set to initial",
        modbus.comm_loss_timeout.count() == 0
            ? std::string("off")
            : fmt::format("outputs to safe after {} without a request",
                          format_duration(modbus.comm_loss_timeout)),
        config::to_string(config.log_level));
    for (const auto& link : config.links) {
        const bool id2 = link.protocol == config::Protocol::id2;
        text += fmt::format(
            "link {}: {} on {}, {} baud, unit {}, timeout {}, retries {}, max_pending_writes {}\n",
            link.name, id2 ? "ID-2" : "ioport hub", link.device, link.baud, link.unit_id,
            format_duration(link.timeout), link.retries, link.max_pending_writes);
        for (const auto& module : link.modules) {
            const bool output = is_output(module.address.type);
            text += fmt::format(
                "  {:<8} {}\n", to_string(module.address),
                output ? fmt::format("initial 0x{:04X}, safe 0x{:04X}, refresh {}", module.initial,
                                     module.safe, format_duration(module.refresh))
                : module.poll.count() == 0
                    ? std::string("every cycle")
                    : fmt::format("poll every {}", format_duration(module.poll)));
            text += tags_text(module);
        }
    }
    for (const auto& warning : config::warnings(config))
        text += fmt::format("warning: {}\n", warning);
    return text;
}

}  // namespace ioport::daemon
