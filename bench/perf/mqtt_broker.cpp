#include "bench/perf/mqtt_broker.hpp"

#include <arpa/inet.h>
#include <mosquitto.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <fstream>
#include <thread>
#include <utility>

#include <fmt/format.h>

namespace ioport::bench {
namespace {

std::uint16_t free_port() {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return 0;
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t length = sizeof address;
    std::uint16_t port = 0;
    if (::bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address) == 0 &&
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) == 0)
        port = ntohs(address.sin_port);
    ::close(fd);
    return port;
}

bool accepts(std::uint16_t port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return false;
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(port);
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    const bool ok = ::connect(fd, reinterpret_cast<const sockaddr*>(&address), sizeof address) == 0;
    ::close(fd);
    return ok;
}

}  // namespace

Broker::Broker(const Environment& env, const TempDir& dir, std::optional<int> cpu)
    : mosquitto_(env.binaries.mosquitto), dir_(dir.path()), cpu_(cpu) {
    if (::access(mosquitto_.c_str(), X_OK) != 0) {
        why_ = fmt::format("no broker at {} (--mosquitto PATH)", mosquitto_);
        return;
    }
    const auto port = free_port();
    std::ofstream(dir / "mosquitto.conf") << fmt::format(
        "listener {} 127.0.0.1\nallow_anonymous true\npersistence false\nsys_interval 1\n"
        "max_queued_messages 100000\nmax_queued_bytes 0\nmax_inflight_messages 0\n"
        "log_type error\nlog_type warning\n",
        port);
    launch(port);
}

bool Broker::restart() {
    const auto port = std::exchange(port_, 0);
    launch(port);
    return started();
}

void Broker::launch(std::uint16_t port) {
    process_ = std::make_unique<Process>(
        std::vector<std::string>{mosquitto_, "-c", dir_ / "mosquitto.conf"}, cpu_,
        dir_ / "mosquitto.log");
    const auto until = Clock::now() + 5s;
    while (Clock::now() < until && process_->running()) {
        if (accepts(port)) {
            port_ = port;
            return;
        }
        std::this_thread::sleep_for(10ms);
    }
    why_ = fmt::format("mosquitto did not start: {}", process_->output());
}

Subscriber::Subscriber(std::uint16_t port, std::vector<std::string> patterns, Handler handler)
    : patterns_(std::move(patterns)), handler_(std::move(handler)) {
    static const int initialised = mosquitto_lib_init();
    (void)initialised;
    client_ = mosquitto_new(nullptr, true, this);
    if (client_ == nullptr) return;
    mosquitto_connect_callback_set(client_, &Subscriber::on_connect);
    mosquitto_subscribe_callback_set(client_, &Subscriber::on_subscribe);
    mosquitto_message_callback_set(client_, &Subscriber::on_message);
    if (mosquitto_connect(client_, "127.0.0.1", port, 60) != MOSQ_ERR_SUCCESS) return;
    if (mosquitto_loop_start(client_) != MOSQ_ERR_SUCCESS) return;
    started_ = true;
    const auto until = Clock::now() + 5s;
    while (Clock::now() < until && !ready())
        std::this_thread::sleep_for(5ms);
}

Subscriber::~Subscriber() {
    if (client_ == nullptr) return;
    if (started_) {
        mosquitto_disconnect(client_);
        mosquitto_loop_stop(client_, false);
    }
    mosquitto_destroy(client_);
}

void Subscriber::on_connect(mosquitto* client, void* self, int rc) {
    if (rc != 0) return;
    for (const auto& pattern : static_cast<Subscriber*>(self)->patterns_)
        mosquitto_subscribe(client, nullptr, pattern.c_str(), 0);
}

void Subscriber::on_subscribe(mosquitto* /*client*/, void* self, int /*mid*/, int /*count*/,
                              const int* /*granted*/) {
    ++static_cast<Subscriber*>(self)->subscribed_;
}

void Subscriber::on_message(mosquitto* /*client*/, void* self, const mosquitto_message* message) {
    const auto at = Clock::now();
    static_cast<Subscriber*>(self)->handler_({at,
                                              message->topic,
                                              {static_cast<const std::uint8_t*>(message->payload),
                                               static_cast<std::size_t>(message->payloadlen)}});
}

}  // namespace ioport::bench
