// The MQTT side of benchmarks 7 and 9: a local mosquitto on a free loopback port, and a
// subscriber in this process (libmosquitto on a thread of its own).
#pragma once

#include <sys/types.h>

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "bench/perf/harness.hpp"

struct mosquitto;
struct mosquitto_message;

namespace ioport::bench {

// mosquitto on a free loopback port, with $SYS every second and room for every QoS 0 message a
// slow subscriber has not taken yet (so that what the broker drops is not what is measured).
class Broker {
  public:
    Broker(const Environment& env, const TempDir& dir, std::optional<int> cpu);
    // An outage: the broker goes away, and comes back on the same port.
    void stop() { process_.reset(); }
    bool restart();
    bool started() const { return port_ != 0; }
    const std::string& why() const { return why_; }
    std::uint16_t port() const { return port_; }
    pid_t pid() const { return process_ ? process_->pid() : -1; }

  private:
    void launch(std::uint16_t port);

    std::string mosquitto_;
    std::filesystem::path dir_;
    std::optional<int> cpu_;
    std::unique_ptr<Process> process_;
    std::uint16_t port_ = 0;
    std::string why_;
};

struct Received {
    Clock::time_point at;
    std::string_view topic;
    std::span<const std::uint8_t> payload;
};

// A subscriber on libmosquitto's own thread (mosquitto_loop_start): `handler` runs there, for
// every message, with the time it arrived.
class Subscriber {
  public:
    using Handler = std::function<void(const Received&)>;

    Subscriber(std::uint16_t port, std::vector<std::string> patterns, Handler handler);
    ~Subscriber();
    Subscriber(const Subscriber&) = delete;
    Subscriber& operator=(const Subscriber&) = delete;

    bool ready() const {
        return started_ && subscribed_.load() == static_cast<int>(patterns_.size());
    }

  private:
    static void on_connect(mosquitto* client, void* self, int rc);
    static void on_subscribe(mosquitto* client, void* self, int mid, int count, const int* granted);
    static void on_message(mosquitto* client, void* self, const mosquitto_message* message);

    std::vector<std::string> patterns_;
    Handler handler_;
    mosquitto* client_ = nullptr;
    bool started_ = false;
    std::atomic<int> subscribed_{0};
};

}  // namespace ioport::bench
