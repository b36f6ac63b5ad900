#include "daemon/http/render.hpp"

#include <ctime>

#include <fmt/format.h>

#include "protocol/exposition.hpp"
#include "protocol/json.hpp"

namespace ioport::daemon {
namespace {

using SystemClock = std::chrono::system_clock;

double seconds(std::chrono::microseconds duration) {
    return std::chrono::duration<double>(duration).count();
}

// The age of a module's last good transaction, as of `now`.
std::optional<double> age(const ModuleState& module, Clock::time_point now) {
    if (!module.last_good) return std::nullopt;
    return std::chrono::duration<double>(now - *module.last_good).count();
}

// One input channel: the name it has in /metrics and its value in engineering units.
struct Channel {
    std::string name;
    double value;
};

// The input channels of a module that has been read: dim16/lim16 inputs 0..15 as 0/1, analog
// channels in engineering units (scaled where configured: the float32 of every other path), the
// ID-2's stop input and count.
std::vector<Channel> input_channels(const ModuleState& module) {
    std::vector<Channel> channels;
    if (!module.address) {
        if (module.stop) channels.push_back({"stop", *module.stop ? 1.0 : 0.0});
        if (module.count) channels.push_back({"count", static_cast<double>(*module.count)});
        return channels;
    }
    const auto type = module.address->type;
    if (!module.reading || is_output(type)) return channels;
    const auto& reading = *module.reading;
    if (full_scale(type) > 0) {
        // raw0…, then value0…: the engineering values the link made when it stored the reading
        const auto count = module.values.size() / 2;
        for (std::size_t ch = 0; ch < count; ++ch)
            channels.push_back({std::to_string(ch), std::get<float>(*module.values[count + ch])});
    } else {
        for (int bit = 0; bit < 16; ++bit)
            channels.push_back({std::to_string(bit), (reading.raw[0] >> bit & 1) != 0 ? 1.0 : 0.0});
    }
    return channels;
}

void link_families(Exposition& out, const Links& links) {
    out.family("ioportd_link_up", "gauge", "1 while the link's serial port is open");
    for (const auto& link : links)
        out.sample("ioportd_link_up", {{"link", link->config().name}}, link->port_open() ? 1 : 0);
    out.family("ioportd_link_transactions_total", "counter",
               "Serial transaction attempts by result");
    for (const auto& link : links) {
        const auto& name = link->config().name;
        const auto& c = link->counters();
        out.sample("ioportd_link_transactions_total", {{"link", name}, {"result", "ok"}},
                   c.transactions_ok);
        out.sample("ioportd_link_transactions_total", {{"link", name}, {"result", "no_answer"}},
                   c.no_answer);
        out.sample("ioportd_link_transactions_total", {{"link", name}, {"result", "bad_answer"}},
                   c.bad_answer);
        out.sample("ioportd_link_transactions_total", {{"link", name}, {"result", "error_ack"}},
                   c.error_ack);
    }
    out.family("ioportd_link_reopens_total", "counter",
               "Times the serial port was opened again after the first open");
    for (const auto& link : links)
        out.sample("ioportd_link_reopens_total", {{"link", link->config().name}},
                   link->counters().reopens());
    out.family("ioportd_link_cycle_seconds", "gauge",
               "Duration of the last complete poll cycle (0 before the first)");
    for (const auto& link : links)
        out.sample("ioportd_link_cycle_seconds", {{"link", link->config().name}},
                   seconds(link->last_cycle()));
    out.family("ioportd_writes_total", "counter",
               "Client writes to the link, by result (busy: refused, the queue was full)");
    for (const auto& link : links)
        for (std::size_t r = 0; r < write_result_count; ++r)
            out.sample(
                "ioportd_writes_total",
                {{"link", link->config().name}, {"result", to_string(static_cast<WriteResult>(r))}},
                link->writes()[r]);
}

// Names and units (gateway.md §6.1) as info metrics, so that a query joins them onto the values:
// ioportd_input_value * on(link, module, channel) group_left(name, unit) ioportd_channel_info.
// Their labels come from the configuration alone: bounded, and no client can add a series.
void info_families(Exposition& out, const Links& links) {
    out.family("ioportd_module_info", "gauge", "The module's configured name (value 1)");
    for (const auto& link : links)
        for (const auto& module : link->modules())
            if (module.address)
                out.sample("ioportd_module_info",
                           {{"link", link->config().name},
                            {"module", module.name},
                            {"name", module.tags->name}},
                           1);
    out.family("ioportd_channel_info", "gauge",
               "Name and unit of an input channel (value 1): every analog channel, and the "
               "digital inputs that have a name");
    for (const auto& link : links)
        for (const auto& module : link->modules()) {
            const auto& tags = *module.tags;
            const auto info = [&](std::size_t channel, const std::string& name,
                                  const std::string& unit) {
                out.sample("ioportd_channel_info",
                           {{"link", link->config().name},
                            {"module", module.name},
                            {"channel", std::to_string(channel)},
                            {"name", name},
                            {"unit", unit}},
                           1);
            };
            for (std::size_t c = 0; c < tags.channels.size(); ++c)
                info(c, tags.channels[c].name, tags.channels[c].unit);
            if (module.address && !is_output(module.address->type))
                for (std::size_t k = 0; k < tags.points.size(); ++k)
                    if (!tags.points[k].empty()) info(k, tags.points[k], "");
        }
}

void module_families(Exposition& out, const Links& links) {
    const auto now = Clock::now();
    out.family("ioportd_module_status", "gauge",
               "Module status (gateway.md 2.3): 1 online, 2 no answer, 3 bad answer or error "
               "ack, 4 not polled yet");
    for (std::size_t l = 0; l < links.size(); ++l)
        for (const auto& module : links[l]->modules())
            out.sample("ioportd_module_status",
                       {{"link", links[l]->config().name}, {"module", module.name}},
                       static_cast<int>(module.status()));
    out.family("ioportd_module_age_seconds", "gauge",
               "Time since the module's last good transaction (absent before the first)");
    for (std::size_t l = 0; l < links.size(); ++l)
        for (const auto& module : links[l]->modules())
            if (const auto seconds = age(module, now))
                out.sample("ioportd_module_age_seconds",
                           {{"link", links[l]->config().name}, {"module", module.name}}, *seconds);
    out.family("ioportd_input_value", "gauge",
               "Last good reading of an input channel: 0/1 for digital inputs, engineering "
               "units for analog channels (scaled where configured, see ioportd_channel_info), "
               "the ID-2's stop (0/1) and count");
    for (std::size_t l = 0; l < links.size(); ++l)
        for (const auto& module : links[l]->modules())
            for (const auto& channel : input_channels(module))
                out.sample("ioportd_input_value",
                           {{"link", links[l]->config().name},
                            {"module", module.name},
                            {"channel", channel.name}},
                           channel.value);
    info_families(out, links);
    out.family("ioportd_output_value", "gauge",
               "Output state the device last confirmed: the dom16 word, the rgbdm colour code, "
               "the mux8m setting (pos << 8 | neg)");
    for (std::size_t l = 0; l < links.size(); ++l)
        for (const auto& module : links[l]->modules())
            if (module.output)
                out.sample("ioportd_output_value",
                           {{"link", links[l]->config().name}, {"module", module.name}},
                           static_cast<int>(*module.output));
}

void process_families(Exposition& out, const ProcessStats& process) {
    out.family("process_cpu_seconds_total", "counter", "User and system CPU time spent");
    out.sample("process_cpu_seconds_total", {}, process.cpu_seconds);
    out.family("process_resident_memory_bytes", "gauge", "Resident memory size");
    out.sample("process_resident_memory_bytes", {}, process.resident_bytes);
    out.family("process_open_fds", "gauge", "Open file descriptors");
    out.sample("process_open_fds", {}, process.open_fds);
    out.family("process_start_time_seconds", "gauge", "Start time of the process, Unix seconds");
    out.sample("process_start_time_seconds", {}, process.start_time_seconds);
}

void module_values(Json& json, const ModuleState& module) {
    if (!module.address) {
        json.key("stop");
        module.stop ? json.value(*module.stop) : json.null();
        json.key("count");
        module.count ? json.value(static_cast<int>(*module.count)) : json.null();
        return;
    }
    const auto type = module.address->type;
    const auto word = [&](std::optional<std::uint16_t> value) {
        json.key("word");
        value ? json.value(static_cast<int>(*value)) : json.null();
    };
    const auto& tags = *module.tags;
    // Named points only, by number: {"5": "pump running"}.
    const auto points = [&](std::string_view key) {
        json.key(key).begin_object();
        for (std::size_t k = 0; k < tags.points.size(); ++k)
            if (!tags.points[k].empty()) json.member(std::to_string(k), tags.points[k]);
        json.end_object();
    };
    switch (type) {
        case ModuleType::dim16:
        case ModuleType::lim16:
            word(module.reading ? std::optional(module.reading->raw[0]) : std::nullopt);
            points("inputs");
            return;
        case ModuleType::dom16:
            word(module.output);
            points("outputs");
            return;
        case ModuleType::acm3p:
        case ModuleType::acm3c:
        case ModuleType::dccim:
        case ModuleType::dcvim: {
            json.key("channels").begin_array();
            for (std::size_t ch = 0; ch < tags.channels.size(); ++ch) {
                const auto& tag = tags.channels[ch];
                json.begin_object();
                if (module.reading) {
                    json.member("raw", static_cast<int>(module.reading->raw[ch]));
                    json.member("value",
                                std::get<float>(*module.values[tags.channels.size() + ch]));
                } else {
                    json.key("raw").null().key("value").null();
                }
                json.member("unit", tag.unit).member("name", tag.name);
                json.key("range").begin_array().value(tag.range[0]).value(tag.range[1]).end_array();
                json.key("scale");
                if (const auto& s = tag.scale)
                    json.begin_array()
                        .value(s->in_lo)
                        .value(s->in_hi)
                        .value(s->out_lo)
                        .value(s->out_hi)
                        .end_array();
                else
                    json.null();
                json.end_object();
            }
            json.end_array();
            return;
        }
        case ModuleType::rgbdm:
            json.key("colour");
            module.output ? json.value(static_cast<int>(*module.output)) : json.null();
            json.key("colour_name");
            module.output&&* module.output < colour_count
                ? json.value(name(static_cast<Colour>(*module.output)))
                : json.null();
            return;
        case ModuleType::mux8m:
            json.key("pos");
            module.output ? json.value(*module.output >> 8) : json.null();
            json.key("neg");
            module.output ? json.value(*module.output & 0xFF) : json.null();
            return;
    }
}

void link_json(Json& json, const LinkScheduler& link, Clock::time_point now) {
    const auto& config = link.config();
    const auto& c = link.counters();
    json.begin_object()
        .member("name", config.name)
        .member("protocol", config::protocol_name(config.protocol))
        .member("device", config.device)
        .member("baud", config.baud)
        .member("unit_id", config.unit_id)
        .member("port_open", link.port_open());
    json.key("cycle_seconds");
    link.last_cycle().count() > 0 ? json.value(seconds(link.last_cycle())) : json.null();
    json.key("transactions")
        .begin_object()
        .member("ok", c.transactions_ok)
        .member("no_answer", c.no_answer)
        .member("bad_answer", c.bad_answer)
        .member("error_ack", c.error_ack)
        .end_object();
    json.member("reopens", c.reopens());
    json.key("writes").begin_object();
    for (std::size_t r = 0; r < write_result_count; ++r)
        json.member(to_string(static_cast<WriteResult>(r)), link.writes()[r]);
    json.end_object();
    json.key("modules").begin_array();
    for (const auto& module : link.modules()) {
        json.begin_object()
            .member("module", module.name)
            .member("name", module.address ? module.tags->name : module.name)
            .member("type", module.address ? name(module.address->type) : "id2")
            .member("number", module.address ? static_cast<int>(module.address->number) : 0)
            .member("slot", module.slot)
            .member("status", static_cast<int>(module.status()))
            .member("status_text", status_text(module.status()));
        json.key("age_seconds");
        const auto seconds = age(module, now);
        seconds ? json.value(*seconds) : json.null();
        module_values(json, module);
        json.end_object();
    }
    json.end_array().end_object();
}

std::string html_escaped(std::string_view text) {
    std::string out;
    out.reserve(text.size());
    for (const char c : text) {
        switch (c) {
            case '&':
                out += "&amp;";
                break;
            case '<':
                out += "&lt;";
                break;
            case '>':
                out += "&gt;";
                break;
            case '"':
                out += "&quot;";
                break;
            default:
                out += c;
        }
    }
    return out;
}

// Styled by the status page's style sheet: the policy every response carries (gateway.md §7.1)
// allows no <style> of its own. The icon spares the browser a request for /favicon.ico, whose
// 404 would land in its console.
std::string map_html(std::span<const gateway::MapRow> rows) {
    std::string html =
        "<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        "<title>ioportd register map</title><link rel=\"icon\" href=\"icon.svg\" "
        "type=\"image/svg+xml\"><link rel=\"stylesheet\" href=\"app.css\">"
        "</head><body class=\"map\"><h1>Register map</h1><p><a href=\"./\">Status</a> · "
        "<a href=\"map?format=csv\">CSV</a> · <a href=\"map?format=md\">Markdown</a></p>"
        "<table><thead><tr><th scope=\"col\">Unit</th><th scope=\"col\">Table</th>"
        "<th scope=\"col\">Address</th><th scope=\"col\">Modicon</th><th scope=\"col\">Module"
        "</th><th scope=\"col\">Channel</th><th scope=\"col\">Type</th><th scope=\"col\">Units"
        "</th><th scope=\"col\">Access</th><th scope=\"col\">Description</th>"
        "<th scope=\"col\">Module name</th><th scope=\"col\">Channel name</th></tr></thead>"
        "<tbody>\n";
    for (const auto& row : rows)
        html += fmt::format(
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>"
            "<td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\n",
            row.unit_id, html_escaped(modbus::to_string(row.table)), row.address,
            gateway::modicon_number(row.table, row.address), html_escaped(row.module),
            html_escaped(row.channel), html_escaped(row.data_type), html_escaped(row.units),
            html_escaped(row.access), html_escaped(row.description), html_escaped(row.module_name),
            html_escaped(row.channel_name));
    html += "</tbody></table></body></html>\n";
    return html;
}

}  // namespace

std::string render_metrics(const GatewayView& gateway, const ProcessStats& process,
                           std::size_t reserve) {
    Exposition out;
    out.reserve(reserve);
    out.family("ioportd_build_info", "gauge", "Always 1; the version in its label");
    out.sample("ioportd_build_info", {{"version", IOPORTD_VERSION}}, 1);
    link_families(out, gateway.links);
    module_families(out, gateway.links);
    for (const auto& output : gateway.outputs)
        output->metrics(out);
    process_families(out, process);
    return out.take();
}

std::string render_state(const GatewayView& gateway, const Caller& caller) {
    const auto now = Clock::now();
    const auto health = daemon::health(gateway.links);
    Json json;
    json.begin_object()
        .member("version", IOPORTD_VERSION)
        .member("time", rfc3339(SystemClock::now()))
        .member("started", rfc3339(gateway.started));
    // Who the page is for (gateway.md §7.1): what it names and whether it offers writes.
    json.key("user");
    if (caller.user.empty())
        json.null();
    else
        json.begin_object()
            .member("name", caller.user)
            .member("operator", caller.operator_)
            .end_object();
    json.key("health").begin_object().member("ok", health.ok).member("reason", health.reason);
    json.end_object();
    json.key("warnings").begin_array();
    for (const auto& warning : config::warnings(gateway.config))
        json.value(warning);
    json.end_array();
    for (const auto& output : gateway.outputs)
        output->state(json);
    json.key("links").begin_array();
    for (const auto& link : gateway.links)
        link_json(json, *link, now);
    json.end_array();
    json.key("events").begin_array();
    for (const auto& event : gateway.events.events())
        json.begin_object()
            .member("seq", event.seq)
            .member("time", rfc3339(event.time))
            .member("kind", to_string(event.kind))
            .member("link", event.link)
            .member("module", event.module)
            .member("client", event.client)
            .member("text", event.text)
            .end_object();
    json.end_array().end_object();
    return json.take();
}

std::string render_trends(const GatewayView& gateway) {
    Json json;
    json.begin_object()
        .member("interval_seconds", static_cast<int>(Trend::interval.count()))
        .member("span_seconds",
                static_cast<int>(Trend::interval.count() * static_cast<int>(Trend::capacity)));
    json.key("series").begin_array();
    for (const auto& link : gateway.links) {
        for (const auto& module : link->modules()) {
            if (!module.trend || !module.address) continue;
            const auto type = module.address->type;
            const auto& tags = *module.tags;
            // The points keep raw words, so the whole span is drawn with today's scale.
            for (std::size_t ch = 0; ch < tags.channels.size(); ++ch) {
                const auto& tag = tags.channels[ch];
                json.begin_object()
                    .member("link", link->config().name)
                    .member("module", module.name)
                    .member("channel", static_cast<int>(ch))
                    .member("name", tag.name)
                    .member("unit", tag.unit);
                json.key("range").begin_array().value(tag.range[0]).value(tag.range[1]).end_array();
                json.key("points").begin_array();
                for (std::size_t i = 0; i < module.trend->size(); ++i) {
                    const auto& point = (*module.trend)[i];
                    json.begin_array()
                        .value(point.time)
                        .value(gateway::channel_value(type, point.raw[ch], tag.scale))
                        .end_array();
                }
                json.end_array().end_object();
            }
        }
    }
    json.end_array().end_object();
    return json.take();
}

std::string render_map(const config::GatewayConfig& config, MapFormat format) {
    std::vector<gateway::MapRow> rows;
    for (const auto& link : config.links) {
        gateway::UnitMap unit{link.protocol == config::Protocol::id2 ? gateway::UnitKind::id2
                                                                     : gateway::UnitKind::ioport,
                              link.unit_id,
                              link.name,
                              {}};
        for (const auto& module : link.modules) {
            unit.modules.push_back(module.address);
            unit.tags.push_back(module.tags);
        }
        auto unit_rows = gateway::map_rows(unit);
        rows.insert(rows.end(), unit_rows.begin(), unit_rows.end());
    }
    switch (format) {
        case MapFormat::csv:
            return gateway::format_csv(rows);
        case MapFormat::markdown:
            return gateway::format_markdown(rows);
        case MapFormat::html:
            break;
    }
    return map_html(rows);
}

HttpResponse render_page(const GatewayView& gateway, const Route& route, const Caller& caller,
                         std::size_t& metrics_bytes) {
    switch (route.page) {
        case Page::status:
            return {200, "text/html; charset=utf-8", std::string(status_page_html)};
        case Page::script:
            return {200, "text/javascript; charset=utf-8", std::string(status_page_js)};
        case Page::style:
            return {200, "text/css; charset=utf-8", std::string(status_page_css)};
        case Page::icon:
            return {200, "image/svg+xml", std::string(status_page_svg)};
        case Page::state:
            return {200, "application/json", render_state(gateway, caller)};
        case Page::trends:
            return {200, "application/json", render_trends(gateway)};
        case Page::metrics: {
            // An eighth more than the last: the counters' digits and the events grow.
            auto text =
                render_metrics(gateway, read_process_stats(), metrics_bytes + metrics_bytes / 8);
            metrics_bytes = text.size();
            return {200, "text/plain; version=0.0.4; charset=utf-8", std::move(text)};
        }
        case Page::health: {
            const auto health = daemon::health(gateway.links);
            return {health.ok ? 200u : 503u, std::string(text_plain),
                    (health.ok ? std::string("ok") : health.reason) + "\n"};
        }
        case Page::map:
            return {200,
                    route.format == MapFormat::html  ? "text/html; charset=utf-8"
                    : route.format == MapFormat::csv ? "text/csv; charset=utf-8"
                                                     : "text/markdown; charset=utf-8",
                    render_map(gateway.config, route.format)};
        case Page::write:  // not a page: HttpOutput answers it
            return {405, std::string(text_plain), "a write is not a page\n"};
    }
    return {404, std::string(text_plain), "no such page\n"};
}

}  // namespace ioport::daemon
