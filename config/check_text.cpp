#include "config/check_text.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "config/duration.hpp"
#include "protocol/sparkplug.hpp"

namespace ioport::config {
namespace {

std::string units_of(const modbus_security::Role& role) {
    std::string units;
    for (std::size_t id = 0; id < role.units.size(); ++id)
        if (role.units.test(id)) units += fmt::format("{}{}", units.empty() ? "units " : ", ", id);
    return units;
}

// What a module's configuration names, units and scales, beyond the defaults (gateway.md §6.1).
std::string tags_text(const ModuleConfig& module) {
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

// An output module's `initial` or `safe` as the configuration writes it: an rgbdm's colour by its
// name, a dom16's word and a mux8m's (pos << 8) | neg in hex.
std::string output_value_text(ModuleType type, std::uint16_t value) {
    switch (type) {
        case ModuleType::rgbdm:
            // Always a colour: the loader takes 0-7 only.
            if (value < colour_count) return std::string(name(static_cast<Colour>(value)));
            break;
        // A dom16's word and a mux8m's (pos << 8) | neg, in hex; input modules have no value.
        case ModuleType::dom16:
        case ModuleType::mux8m:
        case ModuleType::dim16:
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::lim16:
        case ModuleType::dccim:
        case ModuleType::dcvim:
            break;
    }
    return fmt::format("0x{:04X}", value);
}

std::string_view mqtt_versions(MqttProtocol protocol) {
    switch (protocol) {
        case MqttProtocol::automatic:
            return "5, or 3.1.1 if the broker refuses 5";
        case MqttProtocol::v5:
            return "5 only";
        case MqttProtocol::v311:
            return "3.1.1 only";
    }
    return "";
}

}  // namespace

std::string check_config_text(const GatewayConfig& config) {
    const auto& modbus = config.modbus;
    std::string text = fmt::format(
        "Modbus TCP {}, at most {} clients, idle timeout {}, keepalive {}, {}{}, word order "
        "{}, stale {}\n",
        modbus.plain() ? "on " + host_port(modbus.listen_host, modbus.listen_port)
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
            host_port(tls->listen_host, tls->listen_port), tls->certificate,
            tls->default_role.empty() ? "none" : tls->default_role, tls->max_handshakes,
            per_address_handshakes);
        for (const auto& [name, role] : tls->roles)
            text +=
                fmt::format("  role {}: {} of {}\n", name, modbus_security::to_string(role.access),
                            role.units.all() ? std::string("every unit") : units_of(role));
    } else {
        text += "Modbus/TCP Security off\n";
    }
    if (const auto& http = config.http)
        text += fmt::format("HTTP (status page, /metrics, /healthz) on {}, {}\n",
                            host_port(http->listen_host, http->listen_port),
                            http->allow.empty()
                                ? "any client"
                                : fmt::format("{} allowed networks", http->allow.size()));
    else
        text += "HTTP off\n";
    if (const auto& mqtt = config.mqtt) {
        std::vector<std::string> brokers;
        for (const auto& broker : mqtt->brokers)
            brokers.push_back(to_string(broker));
        text += fmt::format(
            "Sparkplug B edge node {}/{} on {} (MQTT {}){}{}\n", mqtt->group_id, mqtt->edge_node_id,
            fmt::join(brokers, ", then "), mqtt_versions(mqtt->protocol),
            mqtt->primary_host_id.empty() ? std::string()
                                          : fmt::format(", primary host {}", mqtt->primary_host_id),
            mqtt->templates ? ", templates (one per module type)" : "");
        if (mqtt->device_id_separator != '.')
            text += fmt::format("Sparkplug device ids with '{}': {}\n", mqtt->device_id_separator,
                                sparkplug::device_id("hub0", ModuleAddress{ModuleType::dim16, 0},
                                                     mqtt->device_id_separator));
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
            brokers.push_back(to_string(broker));
        text += fmt::format("MQTT JSON under {} on {} (MQTT {}), {}\n", json->topic_prefix,
                            fmt::join(brokers, ", then "), mqtt_versions(json->connection.protocol),
                            json->discovery ? fmt::format("Home Assistant discovery under {}",
                                                          json->discovery_prefix)
                                            : std::string("no discovery"));
    } else {
        text += "MQTT JSON off\n";
    }
    text +=
        fmt::format("on shutdown: outputs {}; on communication loss: {}; log level {}\n",
                    config.on_shutdown == OnShutdown::keep ? "kept as they are" : "set to initial",
                    modbus.comm_loss_timeout.count() == 0
                        ? std::string("off")
                        : fmt::format("outputs to safe after {} without a request",
                                      format_duration(modbus.comm_loss_timeout)),
                    to_string(config.log_level));
    for (const auto& link : config.links) {
        const bool id2 = link.protocol == Protocol::id2;
        text += fmt::format(
            "link {}: {} on {}, {} baud, unit {}, timeout {}, retries {}, max_pending_writes {}\n",
            link.name, id2 ? "ID-2" : "ioport hub", link.device, link.baud, link.unit_id,
            format_duration(link.timeout), link.retries, link.max_pending_writes);
        for (const auto& module : link.modules) {
            const bool output = is_output(module.address.type);
            text += fmt::format(
                "  {:<8} {}\n", to_string(module.address),
                output ? fmt::format("initial {}, safe {}, refresh {}",
                                     output_value_text(module.address.type, module.initial),
                                     output_value_text(module.address.type, module.safe),
                                     format_duration(module.refresh))
                : module.poll.count() == 0
                    ? std::string("every cycle")
                    : fmt::format("poll every {}", format_duration(module.poll)));
            text += tags_text(module);
        }
    }
    for (const auto& warning : warnings(config))
        text += fmt::format("warning: {}\n", warning);
    return text;
}

}  // namespace ioport::config
