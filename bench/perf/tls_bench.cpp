// Benchmark 8, what Modbus/TCP Security costs (issue 18, gateway.md §5.6), on an ioportd with both
// listeners on, plain and TLS, and certificates made here with the openssl command as docs/tls.md
// tells an operator to (EC P-256, a client certificate with the operator role):
// a. the reads of benchmark 4 on 1, 8 and 64 long-lived connections, over TLS and over plain
//    TCP in alternating pairs of rounds: ioportd's CPU per request, requests/s, latency;
// b. handshakes: a new connection each, with the client's certificate, one request, close; full
//    and resumed (TLS 1.3 tickets, TLS 1.2 session ids), and plain TCP for comparison: how many
//    a second, and ioportd's CPU for each;
// c. ioportd's memory with 256 TLS clients connected, each having made a request, against 256
//    plain clients and none.
#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <thread>

#include <fmt/format.h>

#include "bench/perf/benchmarks.hpp"
#include "bench/perf/certificates.hpp"
#include "bench/perf/load.hpp"
#include "bench/perf/tls_client.hpp"
#include "config/gateway_config.hpp"
#include "daemon/modbus/modbus_tls.hpp"

namespace ioport::bench {
namespace {

// The full bus and dom16 0–7 of benchmark 4, at 115200 baud with line timing.
std::vector<ModuleAddress> bus() {
    auto modules = full_bus();
    const auto outputs = modules_of(ModuleType::dom16);
    modules.insert(modules.end(), outputs.begin(), outputs.end());
    return modules;
}

// ioportd on that bus with both listeners (or, without certificates, the plain one alone), its
// simulator beside it.
struct Setup {
    Setup(const Environment& env, const Certificates* certificates)
        : sim(env, dir / "tty", bus(), {"--baud", "115200", "--turnaround", "0"}),
          gateway(env, dir,
                  gateway_yaml({{dir / "tty", 115200, bus()}}, 300, false, {},
                               certificates != nullptr ? certificates->yaml() : std::string())),
          tls_port(gateway.started() && certificates != nullptr ? gateway.tls_port()
                                                                : std::uint16_t{0}),
          tls(certificates != nullptr) {}
    bool ready() const {
        return sim.ready() && gateway.started() && (tls_port != 0 || !tls) &&
               gateway.wait_until_polling();
    }

    TempDir dir;
    SimProcess sim;
    Gateway gateway;
    std::uint16_t tls_port;
    bool tls;
};

Summary latency_of(LoadResult& result) {
    auto summary =
        summarize(std::vector<double>(result.latency_us.begin(), result.latency_us.end()));
    result.latency_us.clear();
    return summary;
}

std::string listed(const std::vector<double>& ratios) {
    std::string text;
    for (const double r : ratios)
        text += fmt::format("{}{:.3f}", text.empty() ? "" : " ", r);
    return text;
}

// --- a. Long-lived connections ----------------------------------------------------------------

std::vector<Verdict> long_lived(const Environment& env, const Setup& setup,
                                const TlsClientContext& client) {
    const std::vector<int> counts = env.quick ? std::vector{1, 8} : std::vector{1, 8, 64};
    const int pairs = env.quick ? 1 : 7;  // odd: the median of the pairs' ratios is one of them
    const auto window = env.window(3s);
    const auto warmup = env.quick ? 100ms : 500ms;
    std::string version = "?";
    {
        const TlsConnection probe(client, setup.tls_port);
        if (probe.connected()) version = probe.version();
    }
    fmt::print(
        "\n### 8a. Long-lived connections: TLS against plain TCP ({} pairs of rounds of {} ms at "
        "each connection count, alternating)\n\nThe reads of benchmark 4 (FC 03, 04, 02 in turn, "
        "from the image) against one ioportd polling a full bus and dom16 0–7 at 115200 baud, on "
        "its plain listener (libmodbus, as benchmark 4) and on its TLS listener ({}, the "
        "OpenSSL client of bench/perf/tls_client.cpp with an operator's certificate). The "
        "connections are made before each round, so no handshake is in a window. Server CPU "
        "per request: ioportd's run time over the window ÷ the requests answered in it; its "
        "sleeps per request (voluntary context switches) tell how many requests a wake-up "
        "served: a slower client leaves it more of them to pay.\n",
        pairs, window.count(), version);
    std::vector<Verdict> verdicts;
    const Table rounds_table({"connections", "pair", "transport", "req/s", "p50 µs", "p99 µs",
                              "server CPU µs/req", "server sleeps/req", "errors"});
    struct Totals {
        int connections = 0;
        std::array<LoadResult, 2> sides;  // [tls?]
        std::vector<double> cpu_ratios, p99_ratios;
    };
    std::vector<Totals> all;
    for (const int connections : counts) {
        Totals totals{connections, {}, {}, {}};
        std::array<bool, 2> any{};
        std::vector<bool> order{false, true};  // TLS?
        for (int pair = 0; pair < pairs; ++pair) {
            std::array<double, 2> cpu_us{}, p99_us{};
            for (const bool tls : order) {
                auto result = run_load({.port = tls ? setup.tls_port : setup.gateway.port(),
                                        .server = setup.gateway.pid(),
                                        .connections = connections,
                                        .mix = Mix::reads,
                                        .warmup = warmup,
                                        .window = window,
                                        .tls = tls ? &client : nullptr});
                const auto latency = summarize(
                    std::vector<double>(result.latency_us.begin(), result.latency_us.end()));
                rounds_table.row({fmt::format("{}", connections), fmt::format("{}", pair + 1),
                                  tls ? "TLS" : "plain", fmt::format("{:.0f}", result.per_second()),
                                  fmt::format("{:.0f}", latency.p50),
                                  fmt::format("{:.0f}", latency.p99),
                                  fmt::format("{:.2f}", result.cpu_us_per_request()),
                                  fmt::format("{:.2f}", result.sleeps_per_request()),
                                  fmt::format("{}", result.errors)});
                cpu_us[tls] = result.cpu_us_per_request();
                p99_us[tls] = latency.p99;
                auto& side = totals.sides[tls];
                if (any[tls])
                    side.add(std::move(result));
                else
                    side = std::move(result);
                any[tls] = true;
            }
            totals.cpu_ratios.push_back(cpu_us[1] / cpu_us[0]);
            totals.p99_ratios.push_back(p99_us[1] / p99_us[0]);
            std::rotate(order.begin(), order.begin() + 1, order.end());
        }
        all.push_back(std::move(totals));
    }

    fmt::print("\nAll rounds together:\n");
    const Table table({"connections", "transport", "req/s", "p50 µs", "p99 µs", "p99.9 µs",
                       "server CPU µs/req", "server CPU", "server sleeps/req", "errors"});
    for (auto& t : all) {
        auto& plain = t.sides[0];
        auto& tls = t.sides[1];
        const auto plain_latency = latency_of(plain);
        const auto tls_latency = latency_of(tls);
        const auto row = [&](std::string_view name, const LoadResult& r, const Summary& l) {
            table.row({fmt::format("{}", t.connections), std::string(name),
                       fmt::format("{:.0f}", r.per_second()), fmt::format("{:.0f}", l.p50),
                       fmt::format("{:.0f}", l.p99), fmt::format("{:.0f}", l.p999),
                       fmt::format("{:.2f}", r.cpu_us_per_request()),
                       fmt::format("{:.0f} %", r.cpu_percent()),
                       fmt::format("{:.2f}", r.sleeps_per_request()), fmt::format("{}", r.errors)});
        };
        row("plain", plain, plain_latency);
        row("TLS", tls, tls_latency);
        const double cpu = tls.cpu_us_per_request() / plain.cpu_us_per_request();
        const double cpu_median = summarize(t.cpu_ratios).p50;
        const double p99_median = summarize(t.p99_ratios).p50;
        table.row({fmt::format("{}", t.connections), "**TLS / plain**",
                   fmt::format("{:.3f}", tls.per_second() / plain.per_second()),
                   fmt::format("{:.2f}", tls_latency.p50 / plain_latency.p50),
                   fmt::format("{:.2f}", tls_latency.p99 / plain_latency.p99),
                   fmt::format("{:.2f}", tls_latency.p999 / plain_latency.p999),
                   fmt::format("**{:.3f}**", cpu), "", "", ""});
        fmt::print(
            "\n{} connections, pairs' ratios TLS ÷ plain: CPU per request {}, median **{:.3f}**; "
            "p99 {}, median {:.3f}.\n",
            t.connections, listed(t.cpu_ratios), cpu_median, listed(t.p99_ratios), p99_median);
        const bool ok = plain.connected && tls.connected && plain.errors == 0 && tls.errors == 0;
        machine_line(fmt::format(
            R"({{"bench":"tls_modbus","connections":{},"pairs":{},"tls_version":"{}","plain_rps":{:.0f},"tls_rps":{:.0f},"plain_cpu_us":{:.3f},"tls_cpu_us":{:.3f},"cpu_ratio_total":{:.4f},"cpu_ratio_median":{:.4f},"plain_p50_us":{:.0f},"tls_p50_us":{:.0f},"plain_p99_us":{:.0f},"tls_p99_us":{:.0f},"p99_ratio_median":{:.4f},"plain_sleeps_per_req":{:.3f},"tls_sleeps_per_req":{:.3f},"plain_errors":{},"tls_errors":{}}})",
            t.connections, pairs, version, plain.per_second(), tls.per_second(),
            plain.cpu_us_per_request(), tls.cpu_us_per_request(), cpu, cpu_median,
            plain_latency.p50, tls_latency.p50, plain_latency.p99, tls_latency.p99, p99_median,
            plain.sleeps_per_request(), tls.sleeps_per_request(), plain.errors, tls.errors));
        verdicts.push_back(
            {fmt::format("8a. CPU/request TLS ÷ plain, {} conn.", t.connections),
             fmt::format("median of {} pairs {:.3f}× (all rounds: {:.2f} vs {:.2f} µs = {:.3f}×; "
                         "{:.0f} vs {:.0f} req/s)",
                         pairs, cpu_median, tls.cpu_us_per_request(), plain.cpu_us_per_request(),
                         cpu, tls.per_second(), plain.per_second()),
             "<= 1.5×", ok && cpu_median <= 1.5});
    }
    return verdicts;
}

// --- b. Handshakes ----------------------------------------------------------------------------

std::vector<Verdict> handshakes(const Environment& env, const Setup& setup,
                                const Certificates& certificates) {
    constexpr int clients = 8;
    const int rounds = env.quick ? 1 : 3;
    const auto window = env.window(3s);
    const TlsClientContext tls13(certificates.client(TLS1_3_VERSION));
    const TlsClientContext tls12(certificates.client(TLS1_2_VERSION, true));
    if (!tls13.ok() || !tls12.ok())
        return {{"8b. handshakes",
                 fmt::format("the client did not start: {}{}", tls13.failure(), tls12.failure()),
                 "", false}};
    struct Mode {
        std::string name;
        const TlsClientContext* tls;
        bool resume;
    };
    const std::vector<Mode> modes{{"plain TCP (libmodbus)", nullptr, false},
                                  {"TLS 1.3, full handshake", &tls13, false},
                                  {"TLS 1.3, resumed (ticket)", &tls13, true},
                                  {"TLS 1.2, full handshake", &tls12, false},
                                  {"TLS 1.2, resumed (session id)", &tls12, true}};
    std::vector<std::optional<LoadResult>> totals(modes.size());
    fmt::print(
        "\n### 8b. A connection per request ({} rounds of {} ms per kind, in turn)\n\n{} client "
        "threads, each in a loop: connect, the TLS handshake with the operator's certificate "
        "(verifying the server's), one read (FC 03, 04, 02 in turn), close_notify and close. "
        "Full: no session offered. Resumed: each thread offers the session its last connection "
        "was given (TLS 1.3: the server's ticket, sent after every handshake; TLS 1.2: the "
        "session id, the client sending no ticket extension), and the client's "
        "SSL_session_reused tells whether it was. The same ioportd as 8a; it logs every TLS "
        "client at info level (to a file here), as it does in service. Server CPU per "
        "connection: ioportd's run time over the window ÷ the connections made in it; a "
        "core's worth is 1 s ÷ that.\n",
        rounds, window.count(), clients);
    for (int round = 0; round < rounds; ++round)
        for (std::size_t m = 0; m < modes.size(); ++m) {
            const auto& mode = modes[m];
            auto result = run_load({.port = mode.tls ? setup.tls_port : setup.gateway.port(),
                                    .server = setup.gateway.pid(),
                                    .connections = clients,
                                    .mix = Mix::reads,
                                    .warmup = env.quick ? 100ms : 500ms,
                                    .window = window,
                                    .tls = mode.tls,
                                    .connection_per_request = true,
                                    .resume = mode.resume});
            if (totals[m])
                totals[m]->add(std::move(result));
            else
                totals[m] = std::move(result);
        }
    const Table table({"connections", "per second", "server CPU", "server CPU µs each",
                       "a core's worth /s", "p50 µs", "p99 µs", "resumed", "errors"});
    std::vector<Verdict> verdicts;
    const auto per_connection_us = [](const LoadResult& r) {
        return microseconds(r.server_cpu) /
               static_cast<double>(std::max<std::uint64_t>(r.connections, 1));
    };
    for (std::size_t m = 0; m < modes.size(); ++m) {
        const auto& mode = modes[m];
        auto& r = *totals[m];
        const auto latency = latency_of(r);
        const double per_s = static_cast<double>(r.connections) / r.seconds;
        const double cpu_us = per_connection_us(r);
        table.row({mode.name, fmt::format("{:.0f}", per_s),
                   fmt::format("{:.0f} %", r.cpu_percent()), fmt::format("{:.0f}", cpu_us),
                   fmt::format("{:.0f}", 1e6 / cpu_us), fmt::format("{:.0f}", latency.p50),
                   fmt::format("{:.0f}", latency.p99),
                   mode.tls ? fmt::format("{} of {}", r.resumed, r.connections) : "",
                   fmt::format("{}", r.errors)});
        machine_line(fmt::format(
            R"({{"bench":"tls_handshakes","kind":"{}","connections":{},"per_s":{:.1f},"server_cpu_pct":{:.2f},"server_cpu_us_each":{:.2f},"per_core_s":{:.0f},"p50_us":{:.0f},"p99_us":{:.0f},"resumed":{},"errors":{}}})",
            mode.name, r.connections, per_s, r.cpu_percent(), cpu_us, 1e6 / cpu_us, latency.p50,
            latency.p99, r.resumed, r.errors));
    }
    const double plain_us = per_connection_us(*totals[0]);
    fmt::print(
        "\nA plain connection costs ioportd {:.0f} µs (connect, one request, close); a TLS one "
        "that, plus its handshake. Where ioportd's CPU is below 100 %, the clients (on the other "
        "CPU, doing as much cryptography per handshake as the server) set the rate, and a core's "
        "worth is what ioportd would sustain.\n",
        plain_us);
    for (std::size_t i = 1; i + 1 < modes.size(); i += 2) {
        const auto& full = *totals[i];
        const auto& resumed = *totals[i + 1];
        const bool every = full.connections > 0 && resumed.connections > 0 && full.resumed == 0 &&
                           resumed.resumed == resumed.connections && full.errors == 0 &&
                           resumed.errors == 0;
        verdicts.push_back(
            {fmt::format("8b. {} handshakes/s, full and resumed", i == 1 ? "TLS 1.3" : "TLS 1.2"),
             fmt::format("full {:.0f}/s, {:.0f} µs of ioportd's CPU each ({:.0f}/s a core); "
                         "resumed {:.0f}/s, {:.0f} µs ({:.0f}/s a core), {} of {} resumed",
                         static_cast<double>(full.connections) / full.seconds,
                         per_connection_us(full), 1e6 / per_connection_us(full),
                         static_cast<double>(resumed.connections) / resumed.seconds,
                         per_connection_us(resumed), 1e6 / per_connection_us(resumed),
                         resumed.resumed, resumed.connections),
             "(reported); every resumption resumed", every});
    }
    return verdicts;
}

// --- c. Memory --------------------------------------------------------------------------------

struct Held {
    bool ok = false;
    Memory idle, held;
    std::string limit;  // ioportd's descriptor limit, from /proc/PID/limits
};

std::string descriptor_limit(pid_t pid) {
    std::ifstream in(fmt::format("/proc/{}/limits", pid));
    std::string line;
    while (std::getline(in, line))
        if (line.starts_with("Max open files")) {
            unsigned long soft = 0, hard = 0;
            if (std::sscanf(line.c_str() + 14, "%lu %lu", &soft, &hard) == 2)
                return fmt::format("{} (hard {})", soft, hard);
        }
    return "?";
}

// A fresh ioportd (both listeners, as in a and b), and `count` clients connected to one of them,
// each having made one request.
Held hold_clients(const Environment& env, const Certificates& certificates,
                  const TlsClientContext* tls, int count) {
    Held result;
    const Setup setup(env, &certificates);
    if (!setup.ready()) return result;
    result.idle = memory(setup.gateway.pid());
    std::vector<std::unique_ptr<ModbusConnection>> plain;
    std::vector<std::unique_ptr<TlsConnection>> secure;
    const std::array<std::uint8_t, 5> read{0x04, 0, 0, 0, 16};
    bool ok = true;
    for (int i = 0; i < count && ok; ++i)
        if (tls) {
            secure.push_back(std::make_unique<TlsConnection>(*tls, setup.tls_port));
            const auto reply = secure.back()->request(1, read);
            ok = reply.answered && !reply.exception;
        } else {
            plain.push_back(std::make_unique<ModbusConnection>(setup.gateway.port()));
            ok = plain.back()->input_registers(0, 16).has_value();
        }
    result.held = memory(setup.gateway.pid());
    result.limit = descriptor_limit(setup.gateway.pid());
    result.ok = ok;
    return result;
}

// What a connection of ioportd's TLS listener holds beyond a plain one, measured here on
// ioportd's own code: a thread of this process plays the server with make_tls_context() and
// daemon::make_tls_stream() (Asio's ssl::stream, as the listener makes it), hands `count` clients
// the handshake and one response, and keeps their streams. OpenSSL's part is what it allocated on
// that thread and still holds (OpenSslAllocations), less what the first connection left behind once
// for all (the thread's error queue, OpenSSL's caches); Asio's, the two record buffers of every
// stream.
struct TlsNeed {
    bool ok = false;
    double openssl_kib = 0;  // per connection
    double asio_kib = 0;
};

TlsNeed tls_need(const Certificates& certificates, const TlsClientContext& client, int count) {
    TlsNeed need;
    if (!OpenSslAllocations::installed()) return need;
    config::TlsSettings settings;
    settings.certificate = certificates.path("server.pem");
    settings.certificate_pem = read_file(certificates.path("server.pem"));
    settings.key_pem = read_file(certificates.path("server.key"));
    settings.client_ca_pem = read_file(certificates.path("ca.pem"));
    const auto context = daemon::make_tls_context(settings);
    if (!context) {
        fmt::print(stderr, "{}\n", context.error().message);
        return need;
    }
    asio::io_context io;
    asio::ip::tcp::acceptor acceptor(io, {asio::ip::address_v4::loopback(), 0});
    const auto port = acceptor.local_endpoint().port();
    std::vector<std::unique_ptr<daemon::TlsStream>> streams;
    std::int64_t first = 0, all = 0;
    std::thread server([&] {
        const OpenSslAllocations::Counting counting;
        const auto before = OpenSslAllocations::live();
        for (int i = 0; i <= count; ++i) {
            asio::ip::tcp::socket socket(io);
            boost::system::error_code ec;
            acceptor.accept(socket, ec);
            if (ec) return;
            auto stream = daemon::make_tls_stream(std::move(socket), **context);
            stream->handshake(asio::ssl::stream_base::server, ec);
            // FC 04, 16 registers, and its response.
            std::array<std::uint8_t, 12> request{};
            if (!ec) asio::read(*stream, asio::buffer(request), ec);
            const std::array<std::uint8_t, 7 + 2 + 32> response{request[0], request[1], 0,    0, 0,
                                                                35,         request[6], 0x04, 32};
            if (!ec) asio::write(*stream, asio::buffer(response), ec);
            if (ec) return;
            streams.push_back(std::move(stream));
            if (i == 0) first = OpenSslAllocations::live() - before;
        }
        all = OpenSslAllocations::live() - before;
        need.ok = true;
    });
    {
        std::vector<std::unique_ptr<TlsConnection>> clients;
        const std::array<std::uint8_t, 5> read{0x04, 0, 0, 0, 16};
        for (int i = 0; i <= count; ++i) {
            clients.push_back(std::make_unique<TlsConnection>(client, port));
            if (!clients.back()->request(1, read).answered) break;
        }
        server.join();
        streams.clear();
    }
    need.openssl_kib = static_cast<double>(all - first) / count / 1024;
    need.asio_kib =
        2.0 * static_cast<double>(asio::ssl::detail::stream_core::max_tls_record_size) / 1024;
    return need;
}

// This process holds one descriptor a client.
void make_room_for(int clients) {
    rlimit limit{};
    if (::getrlimit(RLIMIT_NOFILE, &limit) != 0) return;
    const auto wanted = static_cast<rlim_t>(clients) + 64;
    if (limit.rlim_cur >= wanted) return;
    limit.rlim_cur = std::min(wanted, limit.rlim_max);
    (void)::setrlimit(RLIMIT_NOFILE, &limit);
}

std::vector<Verdict> memory_held(const Environment& env, const Certificates& certificates,
                                 const TlsClientContext& client) {
    const int count = env.quick ? 16 : 256;
    make_room_for(count);
    fmt::print(
        "\n### 8c. Memory with {} clients connected\n\nEach figure from a fresh ioportd "
        "(both listeners, max_connections 300, the bus of 8a): its RSS after start-up, then with "
        "{} clients connected to one listener, each having made one read (FC 04) and holding "
        "its connection open; and, for comparison, an ioportd without a modbus.tls section. RSS "
        "counts the pages of the shared libraries ioportd touched (libcrypto's among them).\n",
        count, count);
    Memory without_tls;
    {
        const Setup bare(env, nullptr);
        if (bare.ready()) without_tls = memory(bare.gateway.pid());
    }
    const auto plain = hold_clients(env, certificates, nullptr, count);
    const auto tls = hold_clients(env, certificates, &client, count);
    if (!plain.ok || !tls.ok)
        return {
            {"8c. RSS with TLS clients", "ioportd did not start, or a client failed", "", false}};
    const auto need = tls_need(certificates, client, count);
    const Table table({"clients", "RSS after start-up MiB", "RSS with the clients MiB",
                       "peak RSS (VmHWM) MiB", "per client KiB"});
    const auto per_client = [&](const Held& h) {
        return (static_cast<double>(h.held.rss_kib) - static_cast<double>(h.idle.rss_kib)) / count;
    };
    const auto row = [&](std::string_view name, const Held& h) {
        table.row({fmt::format("{} {}", count, name), fmt::format("{:.1f}", mib(h.idle.rss_kib)),
                   fmt::format("{:.1f}", mib(h.held.rss_kib)),
                   fmt::format("{:.1f}", mib(h.held.peak_kib)),
                   fmt::format("{:.1f}", per_client(h))});
    };
    table.row({"none, and no modbus.tls section", fmt::format("{:.1f}", mib(without_tls.rss_kib)),
               "", fmt::format("{:.1f}", mib(without_tls.peak_kib)), ""});
    row("plain", plain);
    row("TLS", tls);
    const double tls_extra_kib = per_client(tls) - per_client(plain);
    const double need_kib = need.openssl_kib + need.asio_kib;
    fmt::print(
        "\nTLS's own cost per connection, measured: TLS − plain **{:.1f} KiB** of RSS. What a "
        "connection of ioportd's TLS listener holds beyond a plain one, counted in this process "
        "on ioportd's own code (make_tls_context, Asio's ssl::stream): {}. ioportd's descriptor "
        "limit: {}.\n",
        tls_extra_kib,
        need.ok ? fmt::format("OpenSSL {:.1f} KiB allocated, Asio's stream {:.1f} KiB (its two "
                              "record buffers): **{:.1f} KiB**",
                              need.openssl_kib, need.asio_kib, need_kib)
                : "not counted (OpenSSL's allocation functions could not be replaced)",
        tls.limit);
    // The target: benchmark 5's 16 MiB, and what TLS needs per connection on top.
    const double budget_mib = 16 + need_kib * count / 1024;
    const bool met = need.ok && mib(tls.held.rss_kib) <= budget_mib;
    machine_line(fmt::format(
        R"({{"bench":"tls_memory","clients":{},"no_tls_idle_mib":{:.2f},"plain_idle_mib":{:.2f},"plain_held_mib":{:.2f},"tls_idle_mib":{:.2f},"tls_held_mib":{:.2f},"tls_peak_mib":{:.2f},"plain_kib_each":{:.2f},"tls_kib_each":{:.2f},"tls_extra_kib_each":{:.2f},"openssl_kib_each":{:.2f},"asio_kib_each":{:.2f},"budget_mib":{:.2f},"met":{}}})",
        count, mib(without_tls.rss_kib), mib(plain.idle.rss_kib), mib(plain.held.rss_kib),
        mib(tls.idle.rss_kib), mib(tls.held.rss_kib), mib(tls.held.peak_kib), per_client(plain),
        per_client(tls), tls_extra_kib, need.openssl_kib, need.asio_kib, budget_mib, met));
    return {{fmt::format("8c. RSS, {} TLS clients", count),
             fmt::format("{:.1f} MiB (plain clients {:.1f}, none {:.1f}); TLS {:.1f} KiB a "
                         "connection measured, {:.1f} counted (OpenSSL {:.1f}, Asio {:.1f})",
                         mib(tls.held.rss_kib), mib(plain.held.rss_kib), mib(tls.idle.rss_kib),
                         tls_extra_kib, need_kib, need.openssl_kib, need.asio_kib),
             fmt::format("<= 16 MiB + {} × {:.1f} KiB = {:.1f} MiB", count, need_kib, budget_mib),
             met}};
}

}  // namespace

std::vector<Verdict> tls_cost(const Environment& env) {
    fmt::print(
        "\n## 8. Modbus/TCP Security: the cost of TLS\n\nCertificates made with {} (EC P-256): a "
        "CA, the server's for 127.0.0.1, an operator's client certificate (role extension {}). "
        "ioportd on the server CPU; the clients and the simulator on the client CPU.\n",
        env.binaries.openssl, role_oid);
    const TempDir dir;
    const Certificates certificates(env, dir);
    if (!certificates.ok()) {
        fmt::print(stderr, "making the certificates failed: {}\n", certificates.log());
        return {{"8. TLS", "the certificates could not be made", "", false}};
    }
    const TlsClientContext client(certificates.client());
    if (!client.ok()) return {{"8. TLS", client.failure(), "", false}};
    std::vector<Verdict> verdicts;
    {
        const Setup setup(env, &certificates);
        if (!setup.ready()) return {{"8. TLS", "ioportd did not start", "", false}};
        verdicts = long_lived(env, setup, client);
        const auto more = handshakes(env, setup, certificates);
        verdicts.insert(verdicts.end(), more.begin(), more.end());
    }
    const auto more = memory_held(env, certificates, client);
    verdicts.insert(verdicts.end(), more.begin(), more.end());
    return verdicts;
}

}  // namespace ioport::bench
