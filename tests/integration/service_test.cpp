// ioportd under systemd's service protocol, with a NOTIFY_SOCKET owned by the test: READY once
// started, STATUS kept current, WATCHDOG at a quarter of WatchdogSec, STOPPING on SIGTERM.
#include <poll.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <array>
#include <cstring>

#include <fmt/format.h>

#include "tests/support/gateway.hpp"
#include "tests/support/process.hpp"

namespace ioport::test {
namespace {

using Clock = std::chrono::steady_clock;

// The receiving end of sd_notify: a datagram socket the daemon finds in NOTIFY_SOCKET.
class NotifySocket {
  public:
    explicit NotifySocket(std::string path) : path_(std::move(path)) {
        fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
        sockaddr_un address{};
        address.sun_family = AF_UNIX;
        std::strncpy(address.sun_path, path_.c_str(), sizeof(address.sun_path) - 1);
        EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&address), sizeof(address)), 0)
            << std::strerror(errno);
    }
    ~NotifySocket() { ::close(fd_); }
    NotifySocket(const NotifySocket&) = delete;
    NotifySocket& operator=(const NotifySocket&) = delete;

    // The next message, or "" if none came before `deadline`.
    std::string receive(Clock::time_point deadline) {
        const auto left =
            std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
        pollfd fd{fd_, POLLIN, 0};
        if (::poll(&fd, 1, static_cast<int>(std::max<long long>(0, left.count()))) <= 0) return "";
        std::array<char, 4096> buffer{};
        const auto n = ::recv(fd_, buffer.data(), buffer.size(), 0);
        return n > 0 ? std::string(buffer.data(), static_cast<std::size_t>(n)) : "";
    }
    // Waits for a message containing `text`; returns it, or "".
    std::string wait_for(std::string_view text, std::chrono::milliseconds within) {
        const auto deadline = Clock::now() + within;
        while (Clock::now() < deadline) {
            auto message = receive(deadline);
            if (message.find(text) != std::string::npos) return message;
        }
        return "";
    }
    const std::string& path() const { return path_; }

  private:
    std::string path_;
    int fd_ = -1;
};

std::string hub_yaml(const std::string& device) {
    return fmt::format(R"(modbus: {{ listen: "127.0.0.1:0" }}
links:
  - {{ name: hub0, protocol: ioport, device: {}, timeout: 30ms,
      modules: [{{ type: dim16, number: 0 }}, {{ type: dom16, number: 0 }}] }}
)",
                       device);
}

TEST(ServiceNotify, ReadyStatusWatchdogAndStopping) {
    SimProcess hub("--hub", "dim16:0,dom16:0", {"--no-line-timing"});
    TempDir dir;
    NotifySocket notify(dir / "notify");
    GatewayProcess gateway(hub_yaml(hub.link()), {},
                           {"NOTIFY_SOCKET=" + notify.path(), "WATCHDOG_USEC=400000"});

    const auto ready = notify.wait_for("READY=1", 5s);
    ASSERT_FALSE(ready.empty()) << "no READY=1";
    // Sent after the listener is bound and the port was tried: the port is already open.
    EXPECT_NE(ready.find("STATUS=1 of 1 links up"), std::string::npos) << ready;

    // A quarter of WatchdogSec: about ten in a second; at least three leave room for a slow
    // machine, and none would mean the watchdog is never fed.
    int fed = 0;
    const auto second = Clock::now() + 1s;
    while (Clock::now() < second)
        if (notify.receive(second).find("WATCHDOG=1") != std::string::npos) ++fed;
    EXPECT_GE(fed, 3);

    EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0);
    EXPECT_FALSE(notify.wait_for("STOPPING=1", 1s).empty()) << "no STOPPING=1";
}

TEST(ServiceNotify, StatusFollowsTheLink) {
    SimProcess hub("--hub", "dim16:0,dom16:0", {"--no-line-timing"});
    TempDir dir;
    NotifySocket notify(dir / "notify");
    GatewayProcess gateway(hub_yaml(hub.link()), {}, {"NOTIFY_SOCKET=" + notify.path()});
    ASSERT_FALSE(notify.wait_for("READY=1", 5s).empty());
    hub.ctl("unplug");
    EXPECT_FALSE(notify.wait_for("STATUS=0 of 1 links up", 5s).empty());
    hub.ctl("replug");
    EXPECT_FALSE(notify.wait_for("STATUS=1 of 1 links up, 2 of 2 modules online", 5s).empty());
}

TEST(ServiceNotify, WithoutNotifySocketNothingChanges) {
    SimProcess hub("--hub", "dim16:0", {"--no-line-timing"});
    GatewayProcess gateway(R"(modbus: { listen: "127.0.0.1:0" }
links: [{ name: hub0, protocol: ioport, device: )" +
                           hub.link() +
                           R"(, modules: [{ type: dim16, number: 0 }] }]
)");
    ModbusClient client(gateway.port());
    EXPECT_TRUE(client.read_input_registers(1000, 1));
    EXPECT_EQ(gateway.stop(SIGTERM, 2s), 0);
}

}  // namespace
}  // namespace ioport::test
