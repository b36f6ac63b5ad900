#include "bench/perf/load.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <latch>
#include <memory>
#include <utility>

#include <fmt/format.h>

namespace ioport::bench {
namespace {

struct ThreadResult {
    std::uint64_t requests = 0;
    std::uint64_t errors = 0;
    std::uint64_t exceptions = 0;
    std::uint64_t connections = 0;
    std::uint64_t resumed = 0;
    std::vector<float> latency_us;
};

bool writes(Mix mix, int connection) {
    return mix == Mix::writes || (mix == Mix::mixed && connection % 16 == 15);
}

// One request of the mix; true when it was answered normally.
bool request(modbus_t* context, Mix mix, int connection, std::uint64_t k) {
    std::array<std::uint16_t, 16> registers{};
    std::array<std::uint8_t, 128> bits{};
    if (writes(mix, connection)) {
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

enum class Outcome { answered, exception, failed };

// The same requests as above, over TLS: the PDUs libmodbus sends, and the length of a normal
// response (a write's is its echo).
Outcome request(TlsConnection& connection, Mix mix, int index, std::uint64_t k) {
    std::array<std::uint8_t, 5> pdu{};
    std::size_t expected = pdu.size();
    const auto put = [&](std::uint8_t function, int address, int value) {
        pdu = {function, static_cast<std::uint8_t>(address >> 8),
               static_cast<std::uint8_t>(address), static_cast<std::uint8_t>(value >> 8),
               static_cast<std::uint8_t>(value)};
    };
    if (writes(mix, index)) {
        const int module = index % 8;
        if (k % 2 == 0)
            put(0x06, module, static_cast<int>((k * 2654435761U >> 16) & 0xFFFF));
        else
            put(0x05, module * 16 + static_cast<int>(k / 2 % 16), k / 32 % 2 != 0 ? 0xFF00 : 0);
    } else {
        switch (k % 3) {
            case 0:
                put(0x03, 0, 8);
                expected = 2 + 16;
                break;
            case 1:
                put(0x04, 0, 16);
                expected = 2 + 32;
                break;
            default:
                put(0x02, 0, 128);
                expected = 2 + 16;
                break;
        }
    }
    const auto reply = connection.request(1, pdu);
    if (!reply.answered) return Outcome::failed;
    if (reply.exception) return Outcome::exception;
    return reply.pdu.size() == expected && reply.pdu[0] == pdu[0] ? Outcome::answered
                                                                  : Outcome::failed;
}

// One thread's connection: libmodbus over TCP, or the TLS client.
class Client {
  public:
    Client(const LoadSpec& spec, int index) : spec_(spec), index_(index) {
        if (spec.tls)
            connect_tls();
        else
            plain_ = std::make_unique<ModbusConnection>(spec.port, 1 + index % spec.units, 10s);
    }
    bool connected() const { return spec_.tls ? tls_ && tls_->connected() : plain_->connected(); }
    bool resumed() const { return tls_ && tls_->resumed(); }

    // Closes the connection and makes a new one.
    bool reconnect() {
        if (!spec_.tls) {
            modbus_close(plain_->get());
            return modbus_connect(plain_->get()) == 0;
        }
        tls_.reset();
        return connect_tls();
    }

    Outcome request(std::uint64_t k) {
        if (spec_.tls) {
            const auto outcome = ioport::bench::request(*tls_, spec_.mix, index_, k);
            if (spec_.resume && outcome != Outcome::failed)
                if (auto next = tls_->session()) session_ = std::move(next);
            return outcome;
        }
        if (ioport::bench::request(plain_->get(), spec_.mix, index_, k)) return Outcome::answered;
        return errno > MODBUS_ENOBASE ? Outcome::exception : Outcome::failed;
    }

  private:
    bool connect_tls() {
        tls_ = std::make_unique<TlsConnection>(*spec_.tls, spec_.port,
                                               spec_.resume ? session_.get() : nullptr);
        return tls_->connected();
    }

    const LoadSpec& spec_;
    int index_;
    std::unique_ptr<ModbusConnection> plain_;
    std::unique_ptr<TlsConnection> tls_;
    TlsSession session_;
};

}  // namespace

void LoadResult::add(LoadResult other) {
    connected = connected && other.connected;
    requests += other.requests;
    errors += other.errors;
    exceptions += other.exceptions;
    connections += other.connections;
    resumed += other.resumed;
    seconds += other.seconds;
    server_cpu += other.server_cpu;
    server_sleeps += other.server_sleeps;
    latency_us.insert(latency_us.end(), other.latency_us.begin(), other.latency_us.end());
}

LoadResult run_load(const LoadSpec& spec) {
    LoadResult result;
    std::vector<std::unique_ptr<Client>> connections;
    for (int i = 0; i < spec.connections; ++i) {
        connections.push_back(std::make_unique<Client>(spec, i));
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
            auto& client = *connections[static_cast<std::size_t>(i)];
            for (std::uint64_t k = static_cast<std::uint64_t>(i);; ++k) {
                const auto sent = Clock::now();
                const bool connected = !spec.connection_per_request || client.reconnect();
                const auto outcome = connected ? client.request(k) : Outcome::failed;
                const auto answered = Clock::now();
                if (answered >= to) break;
                if (answered < from) continue;
                if (spec.connection_per_request && connected) {
                    ++mine.connections;
                    if (client.resumed()) ++mine.resumed;
                }
                if (outcome != Outcome::answered) {
                    ++mine.errors;
                    if (outcome == Outcome::exception) ++mine.exceptions;
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
    const auto sleeps_before = sleeps(spec.server);
    if (spec.midway) {
        std::this_thread::sleep_until(from + spec.window / 2);
        spec.midway();
    }
    std::this_thread::sleep_until(to);
    const auto cpu_after = cpu_time(spec.server);
    const auto sleeps_after = sleeps(spec.server);
    for (auto& thread : threads)
        thread.join();
    if (beside.joinable()) beside.join();
    result.seconds = seconds(to - from);
    result.server_cpu = cpu_after - cpu_before;
    result.server_sleeps = sleeps_after - sleeps_before;
    for (auto& mine : results) {
        result.requests += mine.requests;
        result.errors += mine.errors;
        result.exceptions += mine.exceptions;
        result.connections += mine.connections;
        result.resumed += mine.resumed;
        result.latency_us.insert(result.latency_us.end(), mine.latency_us.begin(),
                                 mine.latency_us.end());
    }
    return result;
}

AlternatingRounds alternating_rounds(std::array<const Gateway*, 2> sides, int connections,
                                     int rounds, std::chrono::milliseconds warmup,
                                     std::chrono::milliseconds window, const RoundHooks& hooks) {
    AlternatingRounds out;
    std::array<bool, 2> started{};
    std::array<int, 2> order{1, 0};
    for (int round = 0; round < rounds; ++round) {
        std::array<double, 2> p99{}, cpu{};
        for (const int side : order) {
            const auto& gateway = *sides[static_cast<std::size_t>(side)];
            hooks.before(side);
            LoadSpec spec{gateway.port(), gateway.pid(), connections, Mix::reads, 1,
                          warmup,         window,        {},          {}};
            auto result = run_load(spec);
            const auto latency =
                summarize(std::vector<double>(result.latency_us.begin(), result.latency_us.end()));
            hooks.after(round, side, result, latency, result.seconds + seconds(warmup));
            const auto s = static_cast<std::size_t>(side);
            p99[s] = latency.p99;
            cpu[s] = result.cpu_us_per_request();
            if (std::exchange(started[s], true))
                out.total[s].add(std::move(result));
            else
                out.total[s] = std::move(result);
        }
        out.p99_ratios.push_back(p99[1] / p99[0]);
        out.cpu_ratios.push_back(cpu[1] / cpu[0]);
        std::swap(order[0], order[1]);
    }
    for (std::size_t s = 0; s < 2; ++s) {
        auto& values = out.total[s].latency_us;
        out.latency[s] = summarize(std::vector<double>(values.begin(), values.end()));
        values.clear();
    }
    return out;
}

}  // namespace ioport::bench
