// Serves a DeviceModel on a pseudo-terminal, exposed at a symlink like a USB adapter's
// /dev/serial/by-id/ name, with modelled line timing, unplug/replug and a control socket.
#pragma once

#include <chrono>
#include <map>
#include <optional>
#include <string>

#include "link/asio.hpp"
#include "protocol/error.hpp"
#include "sim/answer_clock.hpp"
#include "sim/control.hpp"
#include "sim/model.hpp"

namespace ioport::sim {

using namespace std::chrono_literals;

struct SimulatorSettings {
    std::string link_path;                    // the symlink to the pty the master opens
    std::optional<std::string> control_path;  // Unix socket for the control language
    int baud = 115200;                        // for line timing: 10 bits a byte
    bool line_timing = true;
    std::chrono::microseconds turnaround = 500us;  // request received → answer starts
};

class Simulator {
  public:
    Simulator(asio::io_context& io, DeviceModel& model, SimulatorSettings settings);
    ~Simulator();
    Simulator(const Simulator&) = delete;
    Simulator& operator=(const Simulator&) = delete;

    Result<> start();
    void stop();  // removes the link and the control socket
    bool plugged() const { return master_.is_open(); }
    const std::string& pty_name() const { return pty_name_; }
    // With line timing: how late the answers went out against their modelled end.
    const AnswerErrors& answer_errors() const { return answer_clock_.errors(); }
    void clear_answer_errors() { answer_clock_.clear_errors(); }

  private:
    using Clock = std::chrono::steady_clock;

    Result<> plug();
    void unplug();
    void apply(const PortAction& action);
    void chatter(std::chrono::microseconds every);
    std::chrono::microseconds wire_time(std::size_t bytes) const;
    asio::awaitable<void> read_requests(std::uint64_t plug_generation);
    asio::awaitable<void> write_answers(std::uint64_t plug_generation);
    asio::awaitable<void> accept_control();
    asio::awaitable<void> serve_control(asio::local::stream_protocol::socket socket);

    asio::io_context& io_;
    DeviceModel& model_;
    SimulatorSettings settings_;
    Clock::time_point started_ = Clock::now();
    asio::posix::stream_descriptor master_;
    int slave_fd_ = -1;  // held open so the pty survives between masters' opens
    std::string pty_name_;
    std::uint64_t plug_generation_ = 0;
    std::multimap<Clock::time_point, std::string> due_;  // answers by the time they finish
    Clock::time_point line_free_{};
    asio::steady_timer answer_timer_;
    AnswerClock answer_clock_;
    asio::steady_timer replug_timer_;
    asio::steady_timer chatter_timer_;  // a noisy line: a byte every interval while it runs
    std::uint64_t chatter_count_ = 0;
    std::optional<asio::local::stream_protocol::acceptor> control_;
};

}  // namespace ioport::sim
