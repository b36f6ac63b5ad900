// The benchmarks of issue 6, of issue 16's HTTP side, of issue 17's Sparkplug edge node and of
// issue 18's Modbus/TCP Security and of issue 28's plain MQTT (bench/README.md). Each prints its
// tables and one machine-readable line per figure, and returns its figures against their targets.
#pragma once

#include <vector>

#include "bench/perf/harness.hpp"

namespace ioport::bench {

// 1. The poll loop's transactions per second against a raw ping-pong on the same pty.
std::vector<Verdict> serial_overhead(const Environment& env);
// 2. Poll cycle time against the modelled wire time of a full bus; the data age clients see.
std::vector<Verdict> scan_cycle(const Environment& env);
// 3. Modbus write → device → response while a full bus is polled.
std::vector<Verdict> write_latency(const Environment& env);
// 4. Modbus TCP throughput, latency and server CPU against a plain libmodbus server.
std::vector<Verdict> modbus_throughput(const Environment& env);
// 5. Peak memory with 8 links and 256 clients; CPU while polling with no clients.
std::vector<Verdict> footprint(const Environment& env);
// 6. The HTTP side: its cost to Modbus while scraped, one scrape's CPU with 8 links, the memory
// of the trend rings; a scrape's CPU with a password and with HTTPS, and Modbus while an operator
// writes over HTTP (issue 39).
std::vector<Verdict> http_cost(const Environment& env);
// 6b-c alone: one scrape's CPU and page faults with 8 links × 72 modules, and the memory.
std::vector<Verdict> http_scrape_cost(const Environment& env);
// 6f alone: Modbus beside a TLS handshake flood of the HTTPS port from one address.
std::vector<Verdict> http_flood_cost(const Environment& env);
// 7. The Sparkplug B edge node (issue 17): input change → DDATA latency against the poll cycle,
// ioportd's CPU with MQTT on and off and Modbus beside it, with every analog value changing.
std::vector<Verdict> sparkplug_cost(const Environment& env);
// 7c. A fleet of edge nodes (Environment::fleet) on one broker; nothing in a --quick run.
std::vector<Verdict> sparkplug_fleet(const Environment& env);
std::vector<Verdict> sparkplug_outage(const Environment& env);
std::vector<Verdict> sparkplug_outage_kill(const Environment& env);
std::vector<Verdict> sparkplug_backlog(const Environment& env);
// 7g. A store full at the largest max_size: start-up, and Modbus while a reload scans it.
std::vector<Verdict> sparkplug_full_store(const Environment& env);
// 7h. Sparkplug templates (issue 41): bytes per DDATA and CPU per change against flat metrics on
// the demo's bus, every analog value changing; the births of 8 links × 72 modules.
std::vector<Verdict> sparkplug_templates(const Environment& env);
// 7i. The edge node in MQTT 3.1.1, through the relay with the 64 KiB bound (gateway.md §7.5),
// against MQTT 5 on the same input.
std::vector<Verdict> sparkplug_relay(const Environment& env);
// 9. Plain MQTT with Home Assistant discovery (issue 28) beside the Sparkplug edge node: CPU and
// messages with every analog value of the demo's bus changing, and Modbus p99 beside it.
std::vector<Verdict> mqtt_json_cost(const Environment& env);
// 8. Modbus/TCP Security (issue 18): ioportd's CPU per request over TLS against plain TCP,
// full and resumed handshakes per second, the memory of 256 TLS clients.
std::vector<Verdict> tls_cost(const Environment& env);
// 10. The cost curve (issue 42): 1, 2, 4, 8 and 16 full buses with every input changing and every
// northbound path on; points read, messages, CPU, RSS, Modbus, DDATA and write latency per size.
std::vector<Verdict> cost_curve(const Environment& env);

}  // namespace ioport::bench
