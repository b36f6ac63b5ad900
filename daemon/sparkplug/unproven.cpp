#include "daemon/sparkplug/unproven.hpp"

namespace ioport::daemon {

std::size_t UnprovenData::bytes_of(const SentData& data) {
    return sizeof(Entry) + data.device.capacity() +
           data.points.capacity() * sizeof(decltype(data.points)::value_type);
}

void UnprovenData::sent(SentData data) {
    const auto bytes = bytes_of(data);
    sent_.push_back(Entry{next_++, bytes, std::move(data)});
    bytes_ += bytes;
    while (bytes_ > max_bytes_ && sent_.size() > 1) {
        bytes_ -= sent_.front().bytes;
        sent_.pop_front();
        ++forgotten_;
    }
}

void UnprovenData::proven(std::uint64_t through) {
    while (!sent_.empty() && sent_.front().number <= through) {
        bytes_ -= sent_.front().bytes;
        sent_.pop_front();
    }
}

std::vector<sparkplug::StoredData> UnprovenData::take() {
    std::vector<sparkplug::StoredData> records;
    records.reserve(sent_.size());
    std::optional<std::optional<ModuleType>> specs_of;
    std::vector<sparkplug::MetricSpec> specs;
    for (auto& entry : sent_) {
        auto& data = entry.data;
        if (specs_of != data.type) {
            specs = sparkplug::module_metrics(data.type);
            specs_of = data.type;
        }
        sparkplug::Payload payload{data.timestamp, std::nullopt, {}};
        payload.metrics.reserve(data.points.size());
        for (const auto& [index, value] : data.points) {
            if (index >= specs.size()) continue;  // not the type's: never sent so
            payload.metrics.push_back(sparkplug::Metric{
                specs[index].name, std::nullopt, data.timestamp,
                static_cast<std::uint32_t>(specs[index].type),
                value ? std::optional(sparkplug::metric_value(*value)) : std::nullopt});
        }
        if (!payload.metrics.empty())
            records.push_back({std::move(data.device), std::move(payload)});
    }
    sent_.clear();
    bytes_ = 0;
    return records;
}

}  // namespace ioport::daemon
