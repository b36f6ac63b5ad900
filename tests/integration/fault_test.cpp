// Faults, against the real ioportd and the real simulator: the serial line misbehaving, the
// port unplugged, a module going silent, and Modbus clients misbehaving. Each scenario runs the
// checked workload of bench/workload.hpp meanwhile and asserts its three things:
//   1. the daemon stays up and keeps serving: it is running at the end, and every request of the
//      workload's clients got a response (no timeout, no reset);
//   2. no value served to a client was ever different from a state the simulated device really
//      had (every read held against the simulator's history, see workload.hpp);
//   3. every write a client saw acknowledged reached the device (a command carrying it was
//      applied between request and response), and every write that did not answered an
//      exception (04 or 0B); a write answered with an exception never became desired state.
// The figures each scenario measures are printed (and recorded as test properties) for
// docs/faults.md.
#include <sys/resource.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <csignal>
#include <filesystem>
#include <iostream>
#include <random>
#include <sstream>
#include <thread>

#include <fmt/format.h>
#include <modbus/modbus.h>

#include "bench/workload.hpp"
#include "tests/support/gateway.hpp"
#include "tests/support/process.hpp"
#include "tests/support/raw_client.hpp"
#include "tests/support/timing.hpp"

namespace ioport::test {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

// 50 ms: on a busy 2-core machine the simulator can be starved of CPU for tens of ms; what it
// then answers late fails those attempts, and an answer owed to an earlier request is never
// taken for a later one's (docs/faults.md).
constexpr auto serial_timeout = 50ms;
constexpr int slot_dim16_1 = 1;
constexpr int slot_dom16_2 = 10;

std::string gateway_config(const std::string& device, const std::string& modbus_extra = "",
                           milliseconds timeout = serial_timeout) {
    return fmt::format("modbus:\n  listen: \"127.0.0.1:0\"\n{}\nlinks:\n{}", modbus_extra,
                       bench::hub_link_yaml(device, timeout, 1));
}

std::string ms(milliseconds value) {
    return fmt::format("{} ms", value.count());
}
std::string ms(std::chrono::microseconds value) {
    return fmt::format("{:.1f} ms", std::chrono::duration<double, std::milli>(value).count());
}

// Median and maximum of measured times.
std::pair<milliseconds, milliseconds> median_max(std::vector<milliseconds> times) {
    if (times.empty()) return {};
    std::ranges::sort(times);
    return {times[times.size() / 2], times.back()};
}

std::uint16_t register_or(ModbusClient& client, int address, std::uint16_t otherwise) {
    const auto value = client.read_input_registers(address, 1);
    return value ? (*value)[0] : otherwise;
}

// Every module online at once. Its bound catches a gateway that never recovers: after the faults
// the simulator itself, kept from the CPU on a busy machine (its pty's kernel worker), was seen
// to answer nothing for 4.5 s, then everything at once.
bool all_online(ModbusClient& client, milliseconds deadline = 30s * slowdown) {
    return eventually([&] { return register_or(client, 1000, 0) == 1; }, deadline);
}

std::uint32_t read_u32(ModbusClient& client, int address) {
    const auto words = client.read_input_registers(address, 2);
    return words ? static_cast<std::uint32_t>((*words)[0]) << 16 | (*words)[1] : 0;
}

// Every fault kind the simulator has and how many transactions it hit.
std::string injected(SimProcess& sim) {
    auto text = sim.ctl("faults");
    if (!text.empty() && text.back() == '\n') text.pop_back();
    return text;
}

// The three assertions every scenario ends with.
void expect_three_things(const bench::Report& report, const GatewayProcess& gateway) {
    EXPECT_TRUE(gateway.running()) << "ioportd died";
    EXPECT_GT(report.reads_ok, 100U);
    EXPECT_GT(report.writes_acked, 20U);
    EXPECT_EQ(report.transport_errors, 0U) << report.summary();
    EXPECT_EQ(report.unexpected_exceptions, 0U) << report.summary();
    EXPECT_EQ(report.wrong_values, 0U) << report.summary();
    EXPECT_EQ(report.lost_writes, 0U) << report.summary();
    EXPECT_EQ(report.unanswered_writes, 0U) << report.summary();
    EXPECT_EQ(report.failed_writes_pushed, 0U) << report.summary();
    std::cout << report.summary();
}

class Faults : public ::testing::Test {
  protected:
    explicit Faults(const std::string& modbus_extra = "", const std::string& log_level = "info")
        : gateway(gateway_config(hub.link(), modbus_extra), {"--log-level", log_level}) {}

    std::unique_ptr<bench::Workload> workload(int clients = 6, double write_share = 0.3) {
        bench::WorkloadSettings settings;
        settings.port = gateway.port();
        settings.sim_control = hub.control();
        settings.clients = clients;
        settings.write_share = write_share;
        settings.timeout = serial_timeout;
        return std::make_unique<bench::Workload>(settings);
    }

    SimProcess hub{"--hub", bench::hub_sim_modules(), {"--no-line-timing", "--seed", "7"}};
    GatewayProcess gateway;
    ModbusClient diagnostics{gateway.port()};
};

// --- The serial line ------------------------------------------------------------------------

TEST_F(Faults, RandomGarbageShortLongLateErrorAckAndSilenceOn1To10PercentOfTransactions) {
    ASSERT_TRUE(all_online(diagnostics));
    auto load = workload();
    ASSERT_TRUE(load->start());
    // Every 250 ms each module gets a new fault kind at a new probability between 1 and 10 %.
    // Late answers come 75 ms after the request: after the 50 ms timeout, inside the silence
    // the link waits for after a failure (a later one would meet the next request and be
    // discarded with its answer: see docs/faults.md).
    const std::vector<std::string> kinds{"silent", "error-ack", "garbage",
                                         "short",  "long",      "delay"};
    std::mt19937 random(11);
    const auto modules = bench::hub_sim_modules();
    const auto started = Clock::now();
    int changes = 0;
    // 7 s, and on until an error ack has reached a client as 04 (what the test checks below):
    // on a loaded machine the clients write less within the 7 s.
    const auto enough = [&] { return since(started) >= 7s && load->snapshot().writes_04 > 0; };
    while (!enough() && since(started) < 60s * slowdown) {
        std::istringstream list(modules);
        std::string module;
        while (std::getline(list, module, ',')) {
            const auto& kind = kinds[random() % kinds.size()];
            const double probability = std::uniform_real_distribution<double>(0.01, 0.10)(random);
            hub.ctl(fmt::format("fault {} {} {:.3f}{}", module, kind, probability,
                                kind == "delay" ? " 75ms" : ""));
        }
        ++changes;
        pace_until(started + changes * 250ms);
    }
    hub.ctl("fault all none");
    const auto faults_stopped = Clock::now();
    EXPECT_TRUE(all_online(diagnostics));
    const auto recovered = since(faults_stopped);
    // A refresh period with every module online, so that the last states are checked too.
    pace_until(Clock::now() + 500ms);
    const auto report = load->finish();

    expect_three_things(report, gateway);
    const auto failed = read_u32(diagnostics, 1006);
    const auto ok = read_u32(diagnostics, 1004);
    figure("serial fault rounds", std::to_string(changes));
    figure("faults injected", injected(hub));
    figure("transactions ok / failed (IR 1004, 1006)", fmt::format("{} / {}", ok, failed));
    figure("writes answered 04 / 0B", fmt::format("{} / {}", report.writes_04, report.writes_0b));
    figure("reads answered 0B (stale)", std::to_string(report.reads_stale));
    figure("all online again after the faults stopped", ms(recovered));
    std::istringstream counts(injected(hub));
    std::string kind;
    std::uint64_t count = 0;
    while (counts >> kind >> count)
        EXPECT_GT(count, 0U) << kind << " was never injected";
    EXPECT_GT(failed, 0U);
    EXPECT_GT(report.writes_04, 0U);  // error acks reached clients as 04
}

// A device that reads its commands seconds late, as a starved machine makes the simulator do
// (gateway.md §3.2, issue 47): stopped with SIGSTOP while the clients write, it reads nothing;
// the gateway answers the writes it sent meanwhile 0B after their timeouts and goes on with
// refreshes, poll reads and the clients' next writes (often the same bit again), all waiting on
// the line. Resumed, the device applies them at once, in the order the gateway sent them,
// seconds after the failed writes were answered, and sends all their answers in one burst.
// Checked:
//   - each word the gateway sent was the desired state of its moment (or a write merged into
//     it), so the device must never see a confirmed write undone by an older word nor a failed
//     value in a word sent after the failure: judged by the order of the line, not by how late
//     the device read it;
//   - no answer of the burst is taken for another request's, which a reply cannot tell apart
//     (it names neither module nor request): an input module's state served for another module
//     is a wrong value (every state is unique per module), and, since the resumed device
//     refuses a share of the commands it buffered ("0"), a write confirmed by another write's
//     "1" is a write the device refused, i.e. a lost write.
// SIGCONT is aimed at a request waiting for its reply: resumed during the silence the link waits
// for after a failure, the device's burst is simply discarded.
TEST_F(Faults, ADeviceThatReadsCommandsSecondsLateGetsThemInTheOrderTheGatewaySentThem) {
    ASSERT_TRUE(all_online(diagnostics));
    std::vector<std::string> outputs;
    std::istringstream list(bench::hub_sim_modules());
    for (std::string module; std::getline(list, module, ',');)
        if (module.starts_with("dom16") || module.starts_with("rgbdm") ||
            module.starts_with("mux8m"))
            outputs.push_back(module);
    ASSERT_FALSE(outputs.empty());
    auto load = workload(6, 0.5);
    ASSERT_TRUE(load->start());
    for (int round = 0; round < 8; ++round) {
        SCOPED_TRACE(round);
        const auto before = load->completed();
        ASSERT_TRUE(eventually([&] { return load->completed() >= before + 100; }, 30s * slowdown));
        hub.ctl("fault all none");  // the last burst is long answered
        const auto failed = load->writes_failed();
        // What the device does once resumed: refuse a third of the commands it buffered.
        for (const auto& module : outputs)
            hub.ctl(fmt::format("fault {} error-ack 0.33", module));
        ASSERT_EQ(::kill(hub.pid(), SIGSTOP), 0);
        // Stopped until six writes have failed, each after its two timeouts and a silence: over
        // a second, and the owners have sent their next writes.
        const bool starved = eventually(
            [&] { return load->writes_failed() >= failed + 6 && load->write_in_flight(); },
            20s * slowdown);
        // Resumed while a request waits for its reply, so that the burst meets it: the link has
        // just given up on a write (its client has the 0B), waits for a silence of one timeout,
        // then sends the next request (a write waits) and waits up to a timeout for the reply.
        const auto seen = load->writes_failed();
        const bool aimed =
            starved && eventually([&] { return load->writes_failed() > seen; }, 20s * slowdown);
        if (aimed) pace_until(Clock::now() + serial_timeout + serial_timeout / 2);
        ASSERT_EQ(::kill(hub.pid(), SIGCONT), 0);
        ASSERT_TRUE(starved) << "the writes to a stopped device did not fail";
        ASSERT_TRUE(aimed) << "no write failed after the first six";
    }
    const auto last = load->completed();
    ASSERT_TRUE(eventually([&] { return load->completed() >= last + 100; }, 30s * slowdown));
    hub.ctl("fault all none");
    EXPECT_TRUE(all_online(diagnostics));
    // A refresh period with every module online, so that the last states are checked too.
    pace_until(Clock::now() + 500ms);
    const auto report = load->finish();
    expect_three_things(report, gateway);
    // The device did read failed writes after their answers: the interleaving was forced.
    EXPECT_GT(report.failed_writes_applied_late, 0U);
}

// --- The port -------------------------------------------------------------------------------

TEST_F(Faults, FiftyUnplugReplugCyclesAtRandomMomentsIncludingDuringWrites) {
    ASSERT_TRUE(all_online(diagnostics));
    const auto opens_before = read_u32(diagnostics, 1008);
    auto load = workload(6, 0.5);
    ASSERT_TRUE(load->start());
    std::mt19937 random(5);
    std::vector<milliseconds> recoveries;
    int during_write = 0;
    for (int cycle = 0; cycle < 50; ++cycle) {
        SCOPED_TRACE(cycle);
        // A random moment: every other cycle the moment a write is on its way to the device.
        const auto wait = milliseconds(random() % 40);
        const auto from = Clock::now();
        eventually(
            [&] { return since(from) >= wait && (cycle % 2 == 0 || load->write_in_flight()); }, 1s);
        const auto out_for = milliseconds(1 + random() % 60);
        const auto opens = read_u32(diagnostics, 1008);
        if (load->write_in_flight()) ++during_write;
        hub.ctl("unplug");
        pace_until(Clock::now() + out_for);  // out for a random time
        hub.ctl("replug");
        const auto replugged = Clock::now();
        // Back: the port reopened once more, and every module is online again.
        ASSERT_TRUE(eventually(
            [&] {
                return register_or(diagnostics, 1000, 0) == 1 &&
                       read_u32(diagnostics, 1008) == opens + 1;
            },
            5s))
            << "not back after the replug";
        recoveries.push_back(std::chrono::duration_cast<milliseconds>(Clock::now() - replugged));
    }
    const auto report = load->finish();
    expect_three_things(report, gateway);
    const auto [median, max] = median_max(recoveries);
    figure("unplug cycles", "50");
    figure("unplugs while a write was in flight", std::to_string(during_write));
    figure("replug to every module online, median", ms(median));
    figure("replug to every module online, max", ms(max));
    figure("writes answered 0B", std::to_string(report.writes_0b));
    EXPECT_EQ(read_u32(diagnostics, 1008), opens_before + 50);  // every replug reopened once
    EXPECT_GE(during_write, 15);
    EXPECT_GT(report.writes_0b, 0U);
    // Reopen attempts at most every 2 s (gateway.md §4), then the restore; the rest is room for
    // a busy machine's scheduling.
    EXPECT_LT(max, 3s * slowdown);
}

// --- A module -------------------------------------------------------------------------------

TEST_F(Faults, AModuleThatStopsAnsweringMidRunAndComesBack) {
    ASSERT_TRUE(all_online(diagnostics));
    auto load = workload(6, 0.4);
    ASSERT_TRUE(load->start());
    ASSERT_TRUE(eventually([&] { return load->completed() > 200; }));
    // An input and an output module go silent; the rest of the hub must not notice.
    hub.ctl("fault dim16:1 silent");
    hub.ctl("fault dom16:2 silent");
    const auto silenced = Clock::now();
    ASSERT_TRUE(eventually([&] { return register_or(diagnostics, 1100 + slot_dim16_1, 0) == 2; }));
    const auto detected = since(silenced);
    ASSERT_TRUE(eventually([&] { return register_or(diagnostics, 1100 + slot_dom16_2, 0) == 2; }));
    const auto output_detected = since(silenced);
    EXPECT_EQ(register_or(diagnostics, 1000, 0), 2);  // open, some module not online
    // Meanwhile the other modules keep being polled: dim16 0's age stays small.
    std::uint16_t worst_age = 0;
    const auto outage_end = Clock::now() + 2s;
    eventually(
        [&] {
            worst_age = std::max(worst_age, register_or(diagnostics, 1200, 65535));
            return Clock::now() >= outage_end;
        },
        5s);
    // The silent input answers 0B, not its last value.
    const auto stale = diagnostics.read_input_registers(1, 1);
    ASSERT_FALSE(stale);
    EXPECT_EQ(stale.error(), 0x0B);
    hub.ctl("fault dim16:1 none");
    hub.ctl("fault dom16:2 none");
    const auto back = Clock::now();
    ASSERT_TRUE(eventually([&] { return register_or(diagnostics, 1100 + slot_dim16_1, 0) == 1; }));
    const auto input_back = since(back);
    ASSERT_TRUE(all_online(diagnostics));
    const auto all_back = since(back);
    pace_until(Clock::now() + 500ms);
    const auto report = load->finish();

    expect_three_things(report, gateway);
    figure("silent input module marked no answer (status 2) after", ms(detected));
    figure("silent output module marked no answer after", ms(output_detected));
    figure("age of the other modules during the outage, worst", fmt::format("{} ms", worst_age));
    figure("answering again to online (status 1), input module", ms(input_back));
    figure("answering again to every module online", ms(all_back));
    figure("writes answered 0B during the outage", std::to_string(report.writes_0b));
    EXPECT_LT(detected, 3s * slowdown);  // (retries + 1) timeouts and a silence, and a busy machine
    // Each write to the silent module takes the line for (retries + 1) timeouts and a silence,
    // and after each one a due poll read goes first (gateway.md §4): a client that writes to it
    // without pause delays the polls by one such write each. The other modules' age stays
    // bounded (by a generous margin: a busy machine stretches every step, and so does the
    // sanitizer build, where a clean CI run once measured 3,123 ms).
    EXPECT_LT(milliseconds(worst_age), 60 * serial_timeout * slowdown);
    EXPECT_GT(report.writes_0b, 0U);
    EXPECT_GT(report.reads_stale, 0U);
    EXPECT_LT(all_back, 4500ms * slowdown);  // back-off is at most 4 s
}

// --- SCADA falls silent -----------------------------------------------------------------------

// Short, for a few losses in seconds; the workload's readers ask every few ms, so only the
// scenario's silences get there.
constexpr auto comm_loss_timeout = 300ms;

class CommLoss : public Faults {
  protected:
    CommLoss() : Faults(fmt::format("  comm_loss_timeout: {}ms", comm_loss_timeout.count())) {}
};

// gateway.md §5.3 under load: the clients write outputs, dom16 1 answers 30 ms late (inside the
// 50 ms timeout), so the coil writes of 16 clients queue, and every client falls silent with
// them in flight; the gateway declares the loss while they still wait. The write in flight
// finishes, the waiting ones are dropped (0B); the writes answered normally must reach the
// device before the safe state does (0 lost writes: none overwritten by anything but a later
// write or a safe state after it), no output may ever be set to a value
// nobody asked for (the safe value only after a real silence), 1020 reads 1 for the first
// request afterwards and 0 for the next; then the clients write again. Every other time the
// port is unplugged during the loss, just after the safe push began: the reopen restores the
// safe state.
TEST_F(CommLoss, ScadaFallsSilentWithWritesInFlightNoWriteLostNoValueNobodyAskedFor) {
    ASSERT_TRUE(all_online(diagnostics));
    bench::WorkloadSettings settings;
    settings.port = gateway.port();
    settings.sim_control = hub.control();
    // 21 clients own one write job each (16 of them a coil of dom16 1), 3 only read.
    settings.clients = 24;
    settings.pause = 5ms;
    settings.timeout = serial_timeout;
    settings.comm_loss_timeout = comm_loss_timeout;
    settings.slack = 250ms * slowdown;
    bench::Workload load(settings);
    ASSERT_TRUE(load.start());
    constexpr int episodes = 4;
    std::vector<milliseconds> silences;
    int unplugged = 0;
    for (int episode = 0; episode < episodes; ++episode) {
        SCOPED_TRACE(episode);
        hub.ctl("fault dom16:1 delay 30ms");
        ASSERT_TRUE(eventually([&] { return load.write_in_flight(); }));
        pace_until(Clock::now() + 300ms);  // the coil writes queue up
        // With the unplug, silent for long enough after the reopen for the refreshes to show
        // what the gateway restored.
        const bool unplug = episode % 2 == 1;
        const auto silence = load.silence(unplug ? 1200ms : 100ms, [&](Clock::time_point held) {
            if (!unplug) return;
            // Just past the moment the gateway declares the loss.
            pace_until(held + comm_loss_timeout + 50ms);
            hub.ctl("unplug 100ms");
            ++unplugged;
        });
        ASSERT_TRUE(silence) << silence.error().message;
        EXPECT_EQ(silence->first, 1) << "1020 for the first request after the silence";
        EXPECT_EQ(silence->second, 0) << "1020 for the second";
        silences.push_back(silence->length);
        hub.ctl("fault dom16:1 none");
        pace_until(Clock::now() + 600ms);  // the clients write again
    }
    EXPECT_TRUE(all_online(diagnostics));
    pace_until(Clock::now() + 500ms);  // a refresh period, so that the last states are checked
    const auto report = load.finish();

    expect_three_things(report, gateway);
    const auto [median, max] = median_max(silences);
    figure("comm-loss episodes", std::to_string(report.silences));
    figure("episodes with an unplug during the loss", std::to_string(unplugged));
    figure("silence, median / max", fmt::format("{} / {}", ms(median), ms(max)));
    figure("writes in flight when the clients fell silent",
           std::to_string(report.writes_in_flight_at_silence));
    figure("safe values seen at the simulator (output modules, per episode)",
           std::to_string(report.safe_pushes));
    figure("first request after read 1020 = 1 / the next read 0",
           fmt::format("{} / {}", report.silences_signalled, report.silences_cleared));
    EXPECT_EQ(report.silences, static_cast<std::uint64_t>(episodes));
    EXPECT_EQ(report.silences_signalled, report.silences);
    EXPECT_EQ(report.silences_cleared, report.silences);
    EXPECT_GT(report.writes_in_flight_at_silence, 0U);
    EXPECT_GE(report.safe_pushes, static_cast<std::uint64_t>(episodes));
    EXPECT_TRUE(gateway.wait_for_log("safe values"));
}

// --- Modbus clients -------------------------------------------------------------------------

// Runs `body` over and over in its own thread until stopped; counts its rounds and failures.
class Misbehaviour {
  public:
    // A round at most every 5 ms: misbehaving, not a denial of service on a 2-core machine.
    Misbehaviour(std::string name, std::function<std::optional<std::string>()> body)
        : name_(std::move(name)), thread_([this, body = std::move(body)] {
              while (!stop_) {
                  pace_until(Clock::now() + 5ms);
                  if (auto failure = body()) {
                      std::lock_guard lock(mutex_);
                      if (failures_.size() < 5) failures_.push_back(*failure);
                      ++failed_;
                  }
                  ++rounds_;
              }
          }) {}
    ~Misbehaviour() { stop(); }
    Misbehaviour(const Misbehaviour&) = delete;
    Misbehaviour& operator=(const Misbehaviour&) = delete;
    void stop() {
        stop_ = true;
        if (thread_.joinable()) thread_.join();
    }
    void expect_ok() {
        stop();
        EXPECT_GT(rounds_.load(), 0) << name_;
        EXPECT_EQ(failed_.load(), 0)
            << name_ << ": " << fmt::format("{}", fmt::join(failures_, "; "));
        figure("rounds of " + name_, std::to_string(rounds_.load()));
    }
    bool stopping() const { return stop_; }

  private:
    std::string name_;
    std::atomic<bool> stop_{false};
    std::atomic<int> rounds_{0};
    std::atomic<int> failed_{0};
    std::mutex mutex_;
    std::vector<std::string> failures_;
    std::thread thread_;
};

class MisbehavingClients : public Faults {
  protected:
    MisbehavingClients() : Faults("  max_connections: 1100", "debug") {}
};

TEST_F(MisbehavingClients, DoNotDisturbTheOthers) {
    ASSERT_TRUE(all_online(diagnostics));
    auto load = workload();
    ASSERT_TRUE(load->start());
    const auto port = gateway.port();
    std::mt19937 seed_random(3);
    // Each misbehaving connection is first answered once, so that its timed checks start when
    // the daemon serves it: a connection opened just after the crowd's 1000 waits in the accept
    // queue until they are all accepted (seconds under the sanitizers on a busy machine). Only
    // a hang keeps a client from being served at all for 30 s.
    const auto served = [](RawClient& client) {
        return client.send(adu(7, 1, pdu(4, {1000, 1}))) && client.receive(30s).has_value();
    };
    const auto closes_silently =
        [port, &served](const Bytes& bytes, milliseconds within) -> std::optional<std::string> {
        RawClient client(port);
        if (!served(client)) return "not served";
        client.send(bytes);
        if (!client.closed_silently(within)) return "not closed silently";
        return std::nullopt;
    };
    std::mt19937 header_random(seed_random());
    Misbehaviour malformed("malformed MBAP headers", [&] {
        // A protocol id other than 0, or a length field of 0 or 1.
        const bool protocol = header_random() % 2 == 0;
        const auto header =
            protocol ? be16({1, static_cast<std::uint16_t>(1 + header_random() % 0xFFFF), 6})
                     : be16({1, 0, static_cast<std::uint16_t>(header_random() % 2)});
        auto frame = header;
        frame.insert(frame.end(), {1, 4, 0x03, 0xE8, 0, 1});
        return closes_silently(frame, 2s * slowdown);
    });
    std::mt19937 length_random(seed_random());
    Misbehaviour oversize("oversize lengths", [&] {
        auto frame = be16({2, 0, static_cast<std::uint16_t>(255 + length_random() % 65281)});
        frame.insert(frame.end(), {1, 4, 0x03, 0xE8, 0, 1});
        return closes_silently(frame, 2s * slowdown);
    });
    std::mt19937 function_random(seed_random());
    Misbehaviour unknown("unknown function codes", [&]() -> std::optional<std::string> {
        RawClient client(port);
        if (!served(client)) return "not served";
        for (int i = 0; i < 20; ++i) {
            std::uint8_t function = 0;
            // Every function but those that work (gateway.md §3.5); 43 works with MEI type 14
            // alone, and this PDU's MEI type is 0.
            do {
                function = static_cast<std::uint8_t>(function_random() % 256);
            } while (function == 0 || (function >= 1 && function <= 6) || function == 15 ||
                     function == 16 || function == 23);  // 43 with MEI type 0 is unknown too
            const auto transaction = static_cast<std::uint16_t>(function_random());
            const auto response = client.ask(1, {function, 0, 0, 0, 1}, transaction);
            if (!response || response->transaction != transaction ||
                response->pdu != Bytes{static_cast<std::uint8_t>(function | 0x80), 0x01})
                return fmt::format("function {:02X} not answered 01", function);
        }
        return std::nullopt;
    });
    std::mt19937 quantity_random(seed_random());
    Misbehaviour quantities("quantities out of range", [&]() -> std::optional<std::string> {
        RawClient client(port);
        if (!served(client)) return "not served";
        for (int i = 0; i < 20; ++i) {
            const std::uint8_t function = quantity_random() % 2 == 0 ? 3 : 1;
            const auto limit = function == 3 ? 125 : 2000;
            const auto quantity = static_cast<std::uint16_t>(
                quantity_random() % 3 == 0 ? 0 : limit + 1 + quantity_random() % (65535 - limit));
            const auto response = client.ask(1, pdu(function, {0, quantity}));
            if (!response || response->exception() != 0x03)
                return fmt::format("FC{:02X} quantity {} not answered 03", function, quantity);
        }
        return std::nullopt;
    });
    Misbehaviour half("half a frame then silence", [&]() -> std::optional<std::string> {
        RawClient client(port);
        if (!served(client)) return "not served";
        const auto frame = adu(9, 1, pdu(4, {1000, 1}));
        client.send(Bytes(frame.begin(), frame.begin() + 5));
        const auto sent = Clock::now();
        if (!client.closed_silently(3s * slowdown)) return "not closed";
        const auto after = since(sent);
        if (after < 900ms || after > 1600ms * slowdown)
            return fmt::format("closed after {} ms", after.count());
        return std::nullopt;
    });
    std::mt19937 pipeline_random(seed_random());
    Misbehaviour pipelined("pipelined requests", [&]() -> std::optional<std::string> {
        RawClient client(port);
        if (!served(client)) return "not served";
        Bytes burst;
        std::vector<std::uint16_t> transactions;
        for (int i = 0; i < 50; ++i) {
            const auto transaction = static_cast<std::uint16_t>(pipeline_random());
            transactions.push_back(transaction);
            const auto request = i % 3 == 0 ? pdu(4, {1000, 10}) : pdu(2, {1000, 72});
            const auto frame = adu(transaction, 1, request);
            burst.insert(burst.end(), frame.begin(), frame.end());
        }
        client.send(burst);
        for (const auto transaction : transactions) {
            const auto response = client.receive();
            if (!response || response->transaction != transaction || response->exception() != 0)
                return std::string("answered out of order, wrongly or not at all");
        }
        return std::nullopt;
    });
    // Reads of 125 registers, never read back: MBs of responses, more than the socket buffers
    // hold. The daemon stops reading its requests and closes it once it has read nothing for
    // 5 s (its log says so: the client itself finds out only by reading).
    const auto deaf_closures = [&] {
        const auto log = gateway.log();
        std::size_t count = 0;
        for (auto at = log.find("read nothing for 5 s"); at != std::string::npos;
             at = log.find("read nothing for 5 s", at + 1))
            ++count;
        return count;
    };
    const auto deaf_closed = [&] { return deaf_closures() > 0; };
    Misbehaviour deaf("never reading the responses", [&]() -> std::optional<std::string> {
        const auto closed_before = deaf_closures();
        RawClient client(port, "127.0.0.1", 4096);
        Bytes burst;
        for (int i = 0; i < 20000; ++i) {
            const auto frame = adu(static_cast<std::uint16_t>(i), 1, pdu(4, {200, 125}));
            burst.insert(burst.end(), frame.begin(), frame.end());
        }
        client.send(burst);
        // Until the daemon has closed it: 5 s after the socket buffers filled, which takes the
        // daemon seconds of answering on a busy machine.
        eventually([&] { return deaf.stopping() || deaf_closures() > closed_before; },
                   30s * slowdown);
        return std::nullopt;
    });
    std::atomic<int> crowd_served{0};
    std::atomic<bool> crowd_done{false};
    Misbehaviour crowd("1000 connections at once", [&]() -> std::optional<std::string> {
        if (crowd_done) {  // once: each round leaves 1000 ports in TIME_WAIT
            eventually([&] { return crowd.stopping(); }, 20s);
            return std::nullopt;
        }
        crowd_done = true;
        std::vector<std::unique_ptr<RawClient>> clients;
        clients.reserve(1000);
        for (int i = 0; i < 1000; ++i)
            clients.push_back(std::make_unique<RawClient>(port));
        for (auto& client : clients)
            client->send(adu(1, 1, pdu(4, {1000, 1})));
        for (auto& client : clients) {
            if (!client->receive(30s)) return std::string("a connection was not served");
            ++crowd_served;
        }
        return std::nullopt;
    });
    // At least 8 s, paced by the workload, and until the deaf client has been closed (5 s after
    // the daemon last read from it: later on a busy machine, where its burst takes longer).
    const auto started = Clock::now();
    EXPECT_TRUE(eventually([&] { return since(started) >= 8s && deaf_closed(); }, 20s * slowdown));
    for (auto* misbehaviour :
         {&malformed, &oversize, &unknown, &quantities, &half, &pipelined, &deaf, &crowd})
        misbehaviour->expect_ok();
    const auto report = load->finish();
    expect_three_things(report, gateway);
    figure("crowd connections served", std::to_string(crowd_served.load()));
    figure("read latency of the well-behaved clients, max", ms(report.read_latency.max));
    figure("read latency of the well-behaved clients, p99", ms(report.read_latency.p99));
    EXPECT_EQ(crowd_served.load(), 1000);
    EXPECT_TRUE(deaf_closed());
    // Reads are answered from the image; what delays them here is the crowd's 1000 connections
    // being accepted and the machine. The sanitized build, beside other tests on two cores,
    // once measured a p99 of 158 ms: the bound leaves room for that, not for a wait on a client.
    EXPECT_LT(report.read_latency.p99, 100ms * slowdown);
}

// --- A client that trickles its request ----------------------------------------------------

// The classic libmodbus server: select() over the listener and the clients, modbus_receive()
// and modbus_reply() for the one that is readable. The yardstick for the trickle scenario.
class PlainLibmodbusServer {
  public:
    PlainLibmodbusServer()
        : context_(modbus_new_tcp("127.0.0.1", 0)), mapping_(modbus_mapping_new(0, 0, 0, 1100)) {
        listener_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in address{};
        address.sin_family = AF_INET;
        address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        socklen_t length = sizeof address;
        if (::bind(listener_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0 ||
            ::listen(listener_, 16) != 0 ||
            ::getsockname(listener_, reinterpret_cast<sockaddr*>(&address), &length) != 0)
            ADD_FAILURE() << "the plain libmodbus server cannot listen";
        port_ = ntohs(address.sin_port);
        thread_ = std::thread([this] { serve(); });
    }
    ~PlainLibmodbusServer() {
        stop_ = true;
        thread_.join();
        for (int fd = 0; fd <= max_fd_; ++fd)
            if (FD_ISSET(fd, &clients_)) ::close(fd);
        ::close(listener_);
        modbus_mapping_free(mapping_);
        modbus_free(context_);
    }
    std::uint16_t port() const { return port_; }

  private:
    void serve() {
        FD_ZERO(&clients_);
        max_fd_ = listener_;
        std::array<std::uint8_t, MODBUS_TCP_MAX_ADU_LENGTH> query{};
        while (!stop_) {
            fd_set ready = clients_;
            FD_SET(listener_, &ready);
            timeval tick{0, 50000};
            if (::select(max_fd_ + 1, &ready, nullptr, nullptr, &tick) <= 0) continue;
            if (FD_ISSET(listener_, &ready)) {
                const int fd = ::accept4(listener_, nullptr, nullptr, SOCK_CLOEXEC);
                if (fd >= 0 && fd < FD_SETSIZE) {
                    FD_SET(fd, &clients_);
                    max_fd_ = std::max(max_fd_, fd);
                }
            }
            for (int fd = 0; fd <= max_fd_; ++fd) {
                if (fd == listener_ || !FD_ISSET(fd, &ready)) continue;
                modbus_set_socket(context_, fd);
                const int rc = modbus_receive(context_, query.data());
                if (rc > 0) {
                    modbus_reply(context_, query.data(), rc, mapping_);
                } else if (rc == -1) {
                    ::close(fd);
                    FD_CLR(fd, &clients_);
                }
            }
        }
    }

    modbus_t* context_;
    modbus_mapping_t* mapping_;
    int listener_ = -1;
    std::uint16_t port_ = 0;
    fd_set clients_{};
    int max_fd_ = 0;
    std::atomic<bool> stop_{false};
    std::thread thread_;
};

// Sends `frame` a byte every 0.4 s (after its first `at_once` bytes) while `other` asks for a
// register again and again; the worst time `other` waited for an answer.
milliseconds worst_wait_while_trickling(std::uint16_t port, const Bytes& frame,
                                        std::size_t at_once) {
    RawClient trickler(port);
    RawClient other(port);
    std::atomic<bool> trickled{false};
    std::thread trickle([&] {
        trickler.send(Bytes(frame.begin(), frame.begin() + static_cast<std::ptrdiff_t>(at_once)));
        const auto started = Clock::now();
        for (std::size_t sent = at_once; sent < frame.size(); ++sent) {
            pace_until(started + (sent - at_once + 1) * 400ms);
            trickler.send(Bytes{frame[sent]});
        }
        trickled = true;
    });
    milliseconds worst{};
    eventually(
        [&] {
            const auto asked = Clock::now();
            other.send(adu(5, 1, pdu(4, {1000, 1})));
            if (!other.receive(5s)) return true;
            worst = std::max(worst, since(asked));
            return trickled.load();
        },
        10s);
    trickle.join();
    return worst;
}

TEST_F(Faults, AClientTricklingARequestAByteEvery400msFreezesNoOtherClient) {
    ASSERT_TRUE(all_online(diagnostics));
    // The header at once, then the PDU a byte every 0.4 s: 2 s for the whole request.
    const auto frame = adu(4, 1, pdu(4, {1000, 1}));
    milliseconds plain_worst{};
    {
        PlainLibmodbusServer plain;
        plain_worst = worst_wait_while_trickling(plain.port(), frame, 7);
    }
    auto load = workload();
    ASSERT_TRUE(load->start());
    // ioportd closes the trickler 1 s after its first byte; it comes back once more.
    milliseconds ioportd_worst{};
    for (int i = 0; i < 2; ++i)
        ioportd_worst =
            std::max(ioportd_worst, worst_wait_while_trickling(gateway.port(), frame, 7));
    const auto report = load->finish();
    expect_three_things(report, gateway);
    figure("plain libmodbus select() server: another client's worst wait", ms(plain_worst));
    figure("ioportd: another client's worst wait", ms(ioportd_worst));
    figure("ioportd: the workload's worst read latency meanwhile", ms(report.read_latency.max));
    // Far from the yardstick's seconds, with room for a busy machine's scheduling.
    EXPECT_GE(plain_worst, 1s) << "the yardstick did not freeze: the measurement is wrong";
    // A client frozen behind the trickler waits for all of it, as the yardstick's did; what a
    // busy machine's scheduling adds is far less than half of it (448 ms seen with both cores
    // taken by a build, against 250 ms before as the bound).
    EXPECT_LT(ioportd_worst, plain_worst / 2);
    EXPECT_LT(report.read_latency.max, 500ms * slowdown);
}

// --- More than 1024 connections -------------------------------------------------------------

// Sets the soft RLIMIT_NOFILE for as long as it lives.
class DescriptorLimit {
  public:
    explicit DescriptorLimit(rlim_t soft) {
        ::getrlimit(RLIMIT_NOFILE, &saved_);
        rlimit changed = saved_;
        changed.rlim_cur = std::min(soft, saved_.rlim_max);
        ::setrlimit(RLIMIT_NOFILE, &changed);
    }
    ~DescriptorLimit() { ::setrlimit(RLIMIT_NOFILE, &saved_); }
    DescriptorLimit(const DescriptorLimit&) = delete;
    DescriptorLimit& operator=(const DescriptorLimit&) = delete;

  private:
    rlimit saved_{};
};

class ManyConnections : public ::testing::Test {
  protected:
    static constexpr int connections = 1100;
    static bool enough_descriptors() {
        rlimit limit{};
        ::getrlimit(RLIMIT_NOFILE, &limit);
        return limit.rlim_max == RLIM_INFINITY || limit.rlim_max >= 2 * connections + 200;
    }

    SimProcess hub{"--hub", bench::hub_sim_modules(), {"--no-line-timing"}};
    // Started as systemd starts services: a soft limit of 1024 descriptors.
    std::unique_ptr<GatewayProcess> gateway = [&] {
        DescriptorLimit as_systemd(1024);
        // The serial timeout is not what this is about: 250 ms, so that a busy machine's late
        // simulator does not fail one of the writes counted below (219 of 220 once).
        return std::make_unique<GatewayProcess>(gateway_config(
            hub.link(), fmt::format("  max_connections: {}", connections + 20), 250ms));
    }();
    DescriptorLimit ours{RLIM_INFINITY};  // the test's own connections need more than 1024
};

TEST_F(ManyConnections, MoreThan1024AreServedLikeTheRest) {
    if (!enough_descriptors()) GTEST_SKIP() << "the hard descriptor limit is too low here";
    ModbusClient diagnostics(gateway->port());
    ASSERT_TRUE(all_online(diagnostics));
    // The workload's libmodbus clients select() on their sockets: they are made first, while
    // the test's descriptors are still low. dom16 0 is left to the connections below.
    bench::WorkloadSettings settings;
    settings.port = gateway->port();
    settings.sim_control = hub.control();
    settings.clients = 4;
    settings.write_dom16_0 = false;
    bench::Workload load(settings);
    ASSERT_TRUE(load.start());

    std::vector<std::unique_ptr<RawClient>> clients;
    clients.reserve(connections);
    for (int i = 0; i < connections; ++i) {
        clients.push_back(std::make_unique<RawClient>(gateway->port()));
        ASSERT_TRUE(clients.back()->connected()) << "connection " << i;
    }
    EXPECT_TRUE(eventually([&] { return open_descriptors(gateway->pid()) > 1100; }, 5s * slowdown));
    // Every connection, the newest (highest descriptors) first: a read, and every fifth one a
    // write that goes to the device.
    int served = 0;
    int written = 0;
    std::uint16_t last_written = 0;
    for (int i = connections - 1; i >= 0; --i) {
        auto& client = *clients[static_cast<std::size_t>(i)];
        const auto read = client.ask(1, pdu(4, {1000, 10}), static_cast<std::uint16_t>(i));
        if (read && read->transaction == i && read->exception() == 0 && read->pdu.size() == 22)
            ++served;
        if (i % 5 != 0) continue;
        const auto value = static_cast<std::uint16_t>(0x4000 + i);
        const auto write = client.ask(1, pdu(6, {0, value}));
        if (write && write->pdu == pdu(6, {0, value})) {
            ++written;
            last_written = value;
        }
    }
    const auto report = load.finish();
    EXPECT_EQ(served, connections);
    EXPECT_EQ(written, connections / 5);
    EXPECT_EQ(hub.ctl("get dom16:0"), fmt::format("{}\n", last_written));
    EXPECT_TRUE(gateway->wait_for_log("file descriptor limit raised"));
    figure("connections served", std::to_string(served));
    figure("descriptors open in ioportd", std::to_string(open_descriptors(gateway->pid())));
    expect_three_things(report, *gateway);
}

}  // namespace
}  // namespace ioport::test
