#include "daemon/gateway.hpp"

#include <algorithm>

#include <fmt/format.h>

#include "config/duration.hpp"

namespace ioport::daemon {

Gateway::Gateway(const asio::any_io_executor& executor, config::GatewayConfig config)
    : config_(std::move(config)) {
    std::vector<LinkScheduler*> units;
    for (const auto& link : config_.links) {
        links_.push_back(
            std::make_unique<LinkScheduler>(executor, link, config_.modbus.word_order));
        units.push_back(links_.back().get());
    }
    server_ = std::make_unique<ModbusServer>(executor, config_.modbus, units);
}

Result<> Gateway::start() {
    for (auto& link : links_)
        link->start();
    return server_->start();
}

void Gateway::stop() {
    server_->stop();
    for (auto& link : links_)
        link->stop();
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

std::string describe(const config::GatewayConfig& config) {
    const auto& modbus = config.modbus;
    std::string text = fmt::format(
        "Modbus TCP on {}:{}, at most {} clients, idle timeout {}, {}{}, word order {}, stale "
        "{}\n",
        modbus.listen_host.find(':') != std::string::npos ? "[" + modbus.listen_host + "]"
                                                          : modbus.listen_host,
        modbus.listen_port, modbus.max_connections, format_duration(modbus.idle_timeout),
        modbus.allow.empty() ? "any client"
                             : fmt::format("{} allowed networks", modbus.allow.size()),
        modbus.read_only ? ", read-only" : "",
        modbus.word_order == gateway::WordOrder::big ? "big" : "little",
        modbus.stale == gateway::Stale::exception ? "exception" : "hold");
    for (const auto& link : config.links) {
        const bool id2 = link.protocol == config::Protocol::id2;
        text += fmt::format("link {}: {} on {}, {} baud, unit {}, timeout {}, retries {}\n",
                            link.name, id2 ? "ID-2" : "ioport hub", link.device, link.baud,
                            link.unit_id, format_duration(link.timeout), link.retries);
        for (const auto& module : link.modules) {
            const bool output = is_output(module.address.type);
            text += fmt::format("  {:<8} {}\n", to_string(module.address),
                                output ? fmt::format("initial 0x{:04X}, refresh {}", module.initial,
                                                     format_duration(module.refresh))
                                : module.poll.count() == 0
                                    ? std::string("every cycle")
                                    : fmt::format("poll every {}", format_duration(module.poll)));
        }
    }
    return text;
}

}  // namespace ioport::daemon
