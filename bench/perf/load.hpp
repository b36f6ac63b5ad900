// The Modbus load client of benchmarks 4 and 5: libmodbus, one thread and one connection each,
// every thread sending its next request as soon as it has the response to the last one. Over
// Modbus/TCP Security (benchmark 8) the same requests go through the OpenSSL client of
// tls_client.hpp instead, on long-lived connections or on a new connection each.
#pragma once

#include <sys/types.h>

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <vector>

#include "bench/perf/harness.hpp"
#include "bench/perf/tls_client.hpp"

namespace ioport::bench {

enum class Mix {
    reads,   // FC 03 holding registers 0–7, FC 04 input registers 0–15, FC 02 discrete inputs
             // 0–127, in turn
    writes,  // FC 06 holding register n, FC 05 a coil of dom16 n, in turn (n = connection % 8)
    mixed,   // every 16th connection writes, the others read
};

struct LoadSpec {
    std::uint16_t port = 0;
    pid_t server = -1;  // whose CPU time is measured
    int connections = 1;
    Mix mix = Mix::reads;
    int units = 1;  // connection i talks to unit 1 + i % units
    std::chrono::milliseconds warmup = 500ms;
    std::chrono::milliseconds window = 3s;
    // Called once in the middle of the window (to sample a server's memory, say).
    std::function<void()> midway{};
    // Run on a thread of its own from the window's start; it should return by `to`, the window's
    // end (the HTTP scrapers of benchmark 6, beside the Modbus load).
    std::function<void(Clock::time_point to)> beside{};
    // Modbus/TCP Security: `port` is the TLS listener's, and the connections are this client's.
    const TlsClientContext* tls = nullptr;
    // Every request on a connection of its own: connect (and the TLS handshake), one request,
    // close. The latency is all of it.
    bool connection_per_request = false;
    // With tls and connection_per_request: each connection offers the session its thread's last
    // one was given, as a client that reconnects does.
    bool resume = false;
};

struct LoadResult {
    bool connected = false;
    std::uint64_t requests = 0;    // answered normally within the window
    std::uint64_t errors = 0;      // exceptions and transport failures within the window
    std::uint64_t exceptions = 0;  // of which Modbus exception responses
    // connection_per_request: connections made within the window, and of them how many resumed
    // a TLS session (SSL_session_reused).
    std::uint64_t connections = 0;
    std::uint64_t resumed = 0;
    double seconds = 0;
    std::chrono::nanoseconds server_cpu{};
    std::uint64_t server_sleeps = 0;  // the server's voluntary context switches in the window
    std::vector<float> latency_us;

    double per_second() const { return static_cast<double>(requests) / seconds; }
    double cpu_us_per_request() const {
        return microseconds(server_cpu) / static_cast<double>(std::max<std::uint64_t>(requests, 1));
    }
    double cpu_percent() const { return core_percent(server_cpu, seconds); }
    double sleeps_per_request() const {
        return static_cast<double>(server_sleeps) /
               static_cast<double>(std::max<std::uint64_t>(requests, 1));
    }
    // Adds another run of the same load.
    void add(LoadResult other);
};

LoadResult run_load(const LoadSpec& spec);

// Benchmark 4's reads (`connections`, warm-up, `window`) to each of two servers in turn, in
// `rounds` pairs, the order swapped every round so that the machine's drift falls on both
// alike (7b and 9). Around each round: before(side), then after(round, side, its result, its
// latency, its seconds with the warm-up).
struct AlternatingRounds {
    std::array<LoadResult, 2> total;  // each side's rounds together, latency_us emptied
    std::array<Summary, 2> latency;   // of each side's rounds together
    std::vector<double> p99_ratios;   // side 1 ÷ side 0, per pair
    std::vector<double> cpu_ratios;   // CPU per request, side 1 ÷ side 0, per pair
};
struct RoundHooks {
    std::function<void(int side)> before = [](int) {};
    std::function<void(int round, int side, const LoadResult& result, const Summary& latency,
                       double round_seconds)>
        after;
};
AlternatingRounds alternating_rounds(std::array<const Gateway*, 2> sides, int connections,
                                     int rounds, std::chrono::milliseconds warmup,
                                     std::chrono::milliseconds window, const RoundHooks& hooks);

}  // namespace ioport::bench
