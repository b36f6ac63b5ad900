#include "bench/perf/load.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <latch>
#include <memory>

#include <fmt/format.h>

namespace ioport::bench {
namespace {

struct ThreadResult {
    std::uint64_t requests = 0;
    std::uint64_t errors = 0;
    std::uint64_t exceptions = 0;
    std::vector<float> latency_us;
};

// One request of the mix; true when it was answered normally.
bool request(modbus_t* context, Mix mix, int connection, std::uint64_t k) {
    std::array<std::uint16_t, 16> registers{};
    std::array<std::uint8_t, 128> bits{};
    const bool writes = mix == Mix::writes || (mix == Mix::mixed && connection % 16 == 15);
    if (writes) {
        const int module = connection % 8;
        if (k % 2 == 0)
            return modbus_write_register(context, module,
                                         static_cast<std::uint16_t>(k * 2654435761U >> 16)) == 1;
        const int coil = module * 16 + static_cast<int>(k / 2 % 16);
        return modbus_write_bit(context, coil, static_cast<int>(k / 32 % 2)) == 1;
    }
    switch (k % 3) {
        case 0:
            return modbus_read_registers(context, 0, 8, registers.data()) == 8;
        case 1:
            return modbus_read_input_registers(context, 0, 16, registers.data()) == 16;
        default:
            return modbus_read_input_bits(context, 0, 128, bits.data()) == 128;
    }
}

}  // namespace

void LoadResult::add(LoadResult other) {
    connected = connected && other.connected;
    requests += other.requests;
    errors += other.errors;
    exceptions += other.exceptions;
    seconds += other.seconds;
    server_cpu += other.server_cpu;
    latency_us.insert(latency_us.end(), other.latency_us.begin(), other.latency_us.end());
}

LoadResult run_load(const LoadSpec& spec) {
    LoadResult result;
    std::vector<std::unique_ptr<ModbusConnection>> connections;
    for (int i = 0; i < spec.connections; ++i) {
        connections.push_back(
            std::make_unique<ModbusConnection>(spec.port, 1 + i % spec.units, 10s));
        if (!connections.back()->connected()) {
            fmt::print(stderr, "connection {} of {} to port {} failed\n", i + 1, spec.connections,
                       spec.port);
            return result;
        }
    }
    result.connected = true;
    Clock::time_point from, to;
    std::latch ready(spec.connections);
    std::latch go(1);
    std::vector<ThreadResult> results(static_cast<std::size_t>(spec.connections));
    std::vector<std::thread> threads;
    threads.reserve(static_cast<std::size_t>(spec.connections));
    for (int i = 0; i < spec.connections; ++i)
        threads.emplace_back([&, i] {
            // Below the simulator and this measuring thread, which share the CPU: 256 busy
            // clients must not starve the device the gateway polls, nor delay the CPU readings.
            ::setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()), 10);
            ready.count_down();
            go.wait();
            auto& mine = results[static_cast<std::size_t>(i)];
            auto* context = connections[static_cast<std::size_t>(i)]->get();
            for (std::uint64_t k = static_cast<std::uint64_t>(i);; ++k) {
                const auto sent = Clock::now();
                const bool ok = request(context, spec.mix, i, k);
                const auto answered = Clock::now();
                if (answered >= to) break;
                if (answered < from) continue;
                if (!ok) {
                    ++mine.errors;
                    if (errno > MODBUS_ENOBASE) ++mine.exceptions;
                    continue;
                }
                ++mine.requests;
                mine.latency_us.push_back(static_cast<float>(microseconds(answered - sent)));
            }
        });
    ready.wait();
    from = Clock::now() + spec.warmup;
    to = from + spec.window;
    go.count_down();
    std::thread beside;
    if (spec.beside)
        beside = std::thread([&] {
            std::this_thread::sleep_until(from);
            spec.beside(to);
        });
    std::this_thread::sleep_until(from);
    const auto cpu_before = cpu_time(spec.server);
    if (spec.midway) {
        std::this_thread::sleep_until(from + spec.window / 2);
        spec.midway();
    }
    std::this_thread::sleep_until(to);
    const auto cpu_after = cpu_time(spec.server);
    for (auto& thread : threads)
        thread.join();
    if (beside.joinable()) beside.join();
    result.seconds = seconds(to - from);
    result.server_cpu = cpu_after - cpu_before;
    for (auto& mine : results) {
        result.requests += mine.requests;
        result.errors += mine.errors;
        result.exceptions += mine.exceptions;
        result.latency_us.insert(result.latency_us.end(), mine.latency_us.begin(),
                                 mine.latency_us.end());
    }
    return result;
}

}  // namespace ioport::bench
