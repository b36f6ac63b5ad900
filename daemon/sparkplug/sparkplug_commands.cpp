// What arrives from the broker at the edge node (gateway.md §5.5, §6.2): the primary host's
// STATE, NCMD (rebirth, next server) and DCMD writes, every one of them hostile (see
// sparkplug_node.hpp). Sessions, births and data are in sparkplug_node.cpp.
#include "daemon/sparkplug/sparkplug_node.hpp"

#include <algorithm>

#include <fmt/format.h>

#include "daemon/sparkplug/sparkplug_node_common.hpp"

namespace ioport::daemon {
namespace {

using sparkplug::MessageType;
using sparkplug::Metric;
using sparkplug::Value;
using sparkplug_node::next_server_metric;
using sparkplug_node::now_ms;
using sparkplug_node::rebirth_metric;
using sparkplug_node::shown;
using sparkplug_node::shown_bytes;
using sparkplug_node::type_of;
using sparkplug_node::value_text;

}  // namespace

void SparkplugNode::message(std::string_view topic_text, std::span<const std::uint8_t> payload) {
    const auto topic = sparkplug::parse_topic(topic_text);
    if (!topic) {
        // On the DCMD subscription, so this node's, yet no topic Sparkplug has: a device id of
        // several levels.
        const auto dcmd =
            sparkplug::topic(settings_.group_id, MessageType::dcmd, settings_.edge_node_id, "");
        if (topic_text.starts_with(dcmd + "/")) {
            ++stats_.commands;
            ++stats_.commands_unknown_device;
            refuse("unknown device", {},
                   fmt::format("Sparkplug: a DCMD on {}, which names no device of this edge node "
                               "(its device id has several levels: a broker that turns the '.' "
                               "of topics into '/', as RabbitMQ does, needs another "
                               "device_id_separator; docs/sparkplug.md)",
                               shown(topic_text)));
        }
        return;
    }
    if (topic->type == MessageType::state) {
        if (topic->node == settings_.primary_host_id) host_state(payload);
        return;
    }
    if (topic->group != settings_.group_id || topic->node != settings_.edge_node_id) return;
    if (topic->type == MessageType::ncmd || topic->type == MessageType::dcmd)
        command(*topic, payload);
}

void SparkplugNode::too_large(std::string_view topic_text, std::uint64_t bytes) {
    const auto topic = sparkplug::parse_topic(topic_text);
    if (!topic) return;
    const auto size = fmt::format("{} bytes, more than the {} a message to this node may have",
                                  bytes, sparkplug_maximum_packet_size);
    if (topic->type == MessageType::state) {
        if (topic->node != settings_.primary_host_id) return;
        ++stats_.states.refused;
        refuse("STATE refused", {},
               fmt::format("Sparkplug: STATE of {} refused unread: {}", shown(topic->node), size));
        return;
    }
    if (topic->group != settings_.group_id || topic->node != settings_.edge_node_id) return;
    if (topic->type != MessageType::ncmd && topic->type != MessageType::dcmd) return;
    ++stats_.commands;
    ++stats_.commands_refused;
    // Logged once a minute per device this node has (a bounded set of keys), and once for all
    // the names it does not.
    const bool known =
        std::ranges::any_of(devices_, [&](const Device& d) { return d.id == topic->device; });
    refuse(topic->type == MessageType::ncmd ? std::string("NCMD too large")
           : known                          ? fmt::format("{} too large", topic->device)
                                            : std::string("too large"),
           {},
           fmt::format("Sparkplug: {} refused unread: {}",
                       topic->type == MessageType::ncmd
                           ? std::string("NCMD")
                           : fmt::format("DCMD to {}", shown(topic->device)),
                       size));
}

// The primary host's STATE (Sparkplug 3.0 §7.2). Anyone who may publish on the broker can send one,
// so it is bounded before it is read, and its timestamp, which only orders this host's STATEs,
// is not believed beyond the node's own clock (gateway.md §6.2, docs/sparkplug.md).
void SparkplugNode::host_state(std::span<const std::uint8_t> payload) {
    const auto& host = settings_.primary_host_id;
    const std::string_view json(reinterpret_cast<const char*>(payload.data()), payload.size());
    const auto state = sparkplug::parse_state(json);
    if (!state) {
        ++stats_.states.refused;
        refuse("STATE refused", {},
               fmt::format("Sparkplug: STATE of {} refused: {}{}", host,
                           printable(state.error().message, 4 * shown_bytes),
                           json.size() > sparkplug::max_state_bytes
                               ? std::string()
                               : fmt::format(" (it was {})", shown(json))));
        return;
    }
    const auto now = now_ms();
    const auto tolerance = static_cast<std::uint64_t>(
        std::chrono::duration_cast<std::chrono::milliseconds>(state_clock_tolerance).count());
    if (state->timestamp > now + tolerance) {
        // A clock far ahead of ours, or a forged timestamp: taken for what it says, but it does not
        // become the mark, or every genuine STATE after it would look stale.
        ++stats_.states.ahead;
        refuse("STATE ahead", {},
               fmt::format("Sparkplug: STATE of {} is {} s ahead of this node's clock (more than "
                           "{} s): taken as {}, but not used to judge later STATEs; set both "
                           "clocks by NTP",
                           host, (state->timestamp - now) / 1000, state_clock_tolerance.count(),
                           state->online ? "online" : "offline"));
    } else if (state->timestamp < host_state_timestamp_) {
        // Sparkplug 3.0 §5.4, §5.5: a STATE older than the last one is stale (a retained message
        // from before, a host that came and went): it changes nothing.
        ++stats_.states.stale;
        refuse("STATE stale", {},
               fmt::format("Sparkplug: STATE of {} ignored: its timestamp {} is older than "
                           "the last one, {}",
                           host, state->timestamp, host_state_timestamp_));
        return;
    } else {
        ++stats_.states.taken;
        host_state_timestamp_ = state->timestamp;
    }
    const bool was = host_online_;
    host_online_ = state->online;
    host_timer_.cancel();
    if (state->online && !was) {
        log_.info({}, "Sparkplug: primary host {} online", host);
        birth();
    } else if (!state->online && (born_ || settings_.brokers.size() > 1)) {
        // Sparkplug 3.0 §5.5: a session whose primary host goes offline ends (NDEATH,
        // DISCONNECT) and the node connects to the next server, the same one when it has one;
        // with several, a broker the host is offline on is left at once (gateway.md §6.2).
        walk(fmt::format("the primary host {} is offline on this broker", host));
    } else if (!state->online && was) {
        log_.warn({}, "Sparkplug: primary host {} offline; births when it is back", host);
    }
}

void SparkplugNode::refuse(std::string_view key, const LogFields& fields, std::string text) {
    const auto held = refusals_.admit(key, std::chrono::steady_clock::now());
    if (!held) return;
    text += held_back(*held);
    log_.warn(fields, "{} (logged once a minute per device and reason)", text);
    bus_.publish(
        Note{.kind = EventKind::write, .link = fields.link, .client = "sparkplug", .text = text});
}

void SparkplugNode::command(const sparkplug::Topic& topic, std::span<const std::uint8_t> bytes) {
    if (topic.type == MessageType::ncmd) {
        node_command(bytes);
        return;
    }
    const auto device = std::find_if(devices_.begin(), devices_.end(),
                                     [&](const Device& d) { return d.id == topic.device; });
    if (device == devices_.end()) {
        ++stats_.commands;
        ++stats_.commands_unknown_device;
        refuse("unknown device", {},
               fmt::format("Sparkplug: DCMD to {}, which this edge node does not have",
                           shown(topic.device)));
        return;
    }
    const LogFields fields{
        device->link->config().name, device->link->config().unit_id, {}, "sparkplug"};
    // A DCMD refused whole counts as one command refused: its metrics were never looked at.
    const auto refuse_whole = [&](std::string_view reason, const std::string& why) {
        ++stats_.commands;
        ++stats_.commands_refused;
        refuse(fmt::format("{} {}", device->id, reason), fields,
               fmt::format("Sparkplug DCMD to {} refused: {}", device->id, why));
    };
    if (read_only_) {
        refuse_whole("read_only",
                     "modbus.read_only is set: nothing is written on a client's behalf");
        return;
    }
    const auto payload =
        sparkplug::decode_command(bytes, sparkplug::writable_metrics(type_of(device->module)));
    if (!payload) {
        refuse_whole(payload.error().code == Errc::malformed ? "malformed" : "size",
                     payload.error().message);
        return;
    }
    for (const auto& metric : payload->metrics)
        device_command(*device, metric);
}

void SparkplugNode::node_command(std::span<const std::uint8_t> bytes) {
    const auto payload = sparkplug::decode_command(bytes, node_command_metrics);
    if (!payload) {
        refuse(payload.error().code == Errc::malformed ? "NCMD malformed" : "NCMD size", {},
               fmt::format("Sparkplug NCMD refused: {}", payload.error().message));
        return;
    }
    for (const auto& metric : payload->metrics) {
        if (metric.name == rebirth_metric && metric.value == Value(true)) {
            rebirth_asked();
        } else if (metric.name == next_server_metric && metric.value == Value(true)) {
            if (settings_.brokers.size() > 1)
                walk("the host asked for the next server (NCMD Node Control/Next Server)");
            else
                refuse("NCMD next server", {},
                       fmt::format("Sparkplug: NCMD {} ignored: {} is the only broker",
                                   next_server_metric, client_->broker()));
        } else {
            refuse(
                "NCMD metric", {},
                fmt::format("Sparkplug: NCMD metric {} ignored: only {} or {} = true is a command",
                            metric.name.empty() ? fmt::format("alias {}", metric.alias.value_or(0))
                                                : shown(metric.name),
                            rebirth_metric, next_server_metric));
        }
    }
}

// A host asks again when it missed something; one rebirth a second serves every request in it,
// and the last request is always served: the one waiting goes out when the second is over.
// Meanwhile no DATA goes out (Sparkplug 3.0 rebirth-action-1: stop at once); the births that
// end the wait carry every value that changed.
void SparkplugNode::rebirth_asked() {
    if (rebirth_waiting_) return;
    const auto held = refusals_.admit("NCMD rebirth", std::chrono::steady_clock::now());
    if (held)
        log_.info({}, "Sparkplug: rebirth asked for (NCMD; logged once a minute){}",
                  held_back(*held));
    const auto due = last_nbirth_ ? *last_nbirth_ + min_rebirth_interval
                                  : std::chrono::steady_clock::time_point{};
    if (std::chrono::steady_clock::now() >= due) {
        birth();
        return;
    }
    rebirth_waiting_ = true;
    rebirth_timer_.expires_at(due);
    rebirth_timer_.async_wait([weak = weak_from_this()](const boost::system::error_code& ec) {
        auto self = weak.lock();
        if (!self) return;
        self->rebirth_waiting_ = false;
        if (!ec && !self->stopping_) self->birth();
    });
}

// A DCMD metric: a flat one is a write of its point; with templates, the device's instance
// (by name or by its alias) is a write of each member it holds, as Ignition writes a UDT member
// (gateway.md §7.2). decode_command counted the members against the device's writable metrics.
void SparkplugNode::device_command(Device& device, const Metric& metric) {
    if (!settings_.templates) {
        point_command(device, metric, false);
        return;
    }
    auto named = metric;
    if (named.name.empty() && named.alias == device.first_alias)
        named.name = sparkplug::template_name(type_of(device.module));
    const bool instance =
        named.template_value.has_value() || named.datatype == sparkplug::template_datatype;
    auto writes = sparkplug::command_writes(type_of(device.module), named, true);
    if (!writes) {
        ++stats_.commands;
        ++stats_.commands_refused;
        const LogFields fields{
            device.link->config().name, device.link->config().unit_id, {}, "sparkplug"};
        refuse(fmt::format("{} instance", device.id), fields,
               fmt::format("Sparkplug DCMD to {} refused: {}", device.id,
                           printable(writes.error().message, 4 * shown_bytes)));
        return;
    }
    for (const auto& write : *writes)
        point_command(device, write, instance);
}

void SparkplugNode::point_command(Device& device, const Metric& metric, bool instance) {
    ++stats_.commands;
    std::string name = metric.name;
    // Flat, an alias of the DBIRTH names its metric; with templates only the instance has one.
    if (name.empty() && !settings_.templates && metric.alias &&
        *metric.alias >= device.first_alias &&
        *metric.alias < device.first_alias + device.metrics.size())
        name = device.metrics[static_cast<std::size_t>(*metric.alias - device.first_alias)].name;
    const auto value = value_text(metric.value);
    const auto address =
        instance ? fmt::format("{}/{}/{}", device.id,
                               sparkplug::template_name(type_of(device.module)), shown(name))
                 : fmt::format("{}/{}", device.id, name.empty() ? "?" : shown(name));
    const LogFields fields{
        device.link->config().name, device.link->config().unit_id, {}, "sparkplug"};
    auto plan = sparkplug::plan_command(device.module, name, metric.datatype, metric.value);
    if (!plan) {
        ++stats_.commands_refused;
        // The error names the metric as the host sent it: escaped here, like every broker string.
        refuse(fmt::format("{} metric", device.id), fields,
               fmt::format("Sparkplug DCMD {} = {} refused: {}", address, value,
                           printable(plan.error().message, 4 * shown_bytes)));
        return;
    }
    WriteOrigin origin{.client = "sparkplug",
                       .function = "DCMD",
                       .address = address,
                       .value = value,
                       .request = fmt::format("DCMD {} = {}", address, value)};
    asio::co_spawn(
        executor_,
        [self = shared_from_this(), link = device.link, plan = std::move(*plan),
         origin = std::move(origin), device_id = device.id]() mutable -> asio::awaitable<void> {
            const auto what = origin.request;
            const auto result = co_await link->write(std::move(plan), std::move(origin));
            if (result != WriteResult::busy) co_return;  // audited by the link
            // Never queued, never sent: a refusal like the others, not an audited write.
            ++self->stats_.commands_refused;
            self->refuse(fmt::format("{} busy", device_id),
                         {link->config().name, link->config().unit_id, {}, "sparkplug"},
                         fmt::format("Sparkplug {} refused: {} writes are waiting for link {} "
                                     "(max_pending_writes)",
                                     what, link->config().max_pending_writes, link->config().name));
        },
        asio::detached);
}
}  // namespace ioport::daemon
