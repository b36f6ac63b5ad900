#include "daemon/gateway.hpp"

#include <algorithm>

#include <fmt/format.h>
#include <fmt/ranges.h>

#include "daemon/mqtt_json/mqtt_json_output.hpp"
#include "daemon/sparkplug/sparkplug_output.hpp"

namespace ioport::daemon {

Gateway::Gateway(const asio::any_io_executor& executor, config::GatewayConfig config, Log& log,
                 WorkerThread& disk, WorkerThread& hashing)
    : executor_(executor),
      config_(std::move(config)),
      log_(log),
      disk_(disk),
      recorded_(bus_.subscribe([this](const BusEvent& event) { record(events_, event); })),
      comm_loss_(std::make_shared<CommLossWatch>(executor, log, bus_, [this] { comm_lost(); })),
      modbus_(std::make_shared<ModbusOutput>(executor, log, bus_, comm_loss_)) {
    // The one place that knows every output; adding one is a line here (docs/design.md).
    outputs_ = {modbus_,
                std::make_shared<HttpOutput>(executor, log, bus_, hashing, machine_host_name(),
                                             [this] { return view(); }),
                std::make_shared<SparkplugOutput>(executor, log, bus_, disk_),
                std::make_shared<MqttJsonOutput>(executor, log, bus_)};
}

std::shared_ptr<LinkScheduler> Gateway::make_link(const config::LinkConfig& link) {
    return std::make_shared<LinkScheduler>(executor_, link, log_, bus_);
}

GatewayView Gateway::view() const {
    return {config_, links_, outputs_, events_, started_};
}

void Gateway::comm_lost() {
    // The links running then: a reload replaces links_, not this callback.
    for (auto& link : links_)
        link->enter_safe_state();
}

Result<> Gateway::start() {
    for (const auto& link : config_.links)
        links_.push_back(make_link(link));
    for (auto& link : links_)
        link->start();
    for (auto& output : outputs_)
        if (auto started = output->start(config_, links_); !started) return started;
    comm_loss_->start(config_.modbus.comm_loss_timeout);
    log_warnings();
    return {};
}

void Gateway::log_warnings() {
    for (const auto& warning : config::warnings(config_))
        log_.warn({}, "{}", warning);
}

void Gateway::shut_down(std::function<void()> done) {
    // Shared by the links' and the outputs' callbacks; `done` runs when the last has finished.
    auto remaining = std::make_shared<std::size_t>(links_.size() + outputs_.size());
    auto finished = [remaining, done = std::move(done)] {
        if (--*remaining == 0) done();
    };
    comm_loss_->stop();
    for (auto output = outputs_.rbegin(); output != outputs_.rend(); ++output)
        (*output)->stop(output_stop_deadline, finished);
    for (auto& link : links_)
        link->finish(config_.on_shutdown, finished);
}

void Gateway::stop() {
    comm_loss_->stop();
    for (auto output = outputs_.rbegin(); output != outputs_.rend(); ++output)
        (*output)->stop(std::chrono::milliseconds(0), [] {});
    for (auto& link : links_)
        link->stop();
}

Result<std::string> Gateway::reload(config::GatewayConfig next) {
    for (std::size_t i = 0; i < outputs_.size(); ++i) {
        if (auto prepared = outputs_[i]->prepare(next); !prepared) {
            for (std::size_t j = 0; j < i; ++j)
                outputs_[j]->abandon();
            return Unexpected(prepared.error());
        }
    }
    const bool same_word_order = next.modbus.word_order == config_.modbus.word_order;
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
        if (comm_loss_->lost()) links[i]->enter_safe_state();
    }
    links_ = std::move(links);
    comm_loss_->set_timeout(config_.modbus.comm_loss_timeout);
    std::vector<std::string> sections;
    for (auto& output : outputs_)
        sections.push_back(fmt::format("{} {}", output->name(),
                                       output->apply(config_, links_) ? "changed" : "unchanged"));
    log_warnings();
    const auto list = [](const std::vector<std::string>& of) {
        return of.empty() ? std::string("none") : fmt::format("{}", fmt::join(of, " "));
    };
    auto summary = fmt::format(
        "links kept: {}; restarted: {}; added: {}; removed: {}; {}; names, units or scales "
        "changed: {}",
        list(names.kept), list(names.restarted), list(names.added), list(names.removed),
        fmt::join(sections, "; "), list(names.retagged));
    bus_.publish(Note{.kind = EventKind::reload,
                      .text = fmt::format("configuration reloaded: {}", summary)});
    return summary;
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
                       online, configured, modbus_->connections());
}

bool Gateway::healthy() const {
    const auto now = Clock::now();
    return std::all_of(links_.begin(), links_.end(),
                       [&](const auto& link) { return link->progressing(now); });
}

}  // namespace ioport::daemon
