#!/usr/bin/python3
"""ioportd scraped by a real Prometheus server (Debian's /usr/bin/prometheus): the exposition of
/metrics is one that Prometheus ingests, and a change at a simulated device shows in its queries.

ioport-sim (a hub with dim16 0, dom16 0 and acm3p 0) on a pty, ioportd on it with HTTP on a free loopback
port, Prometheus on another with a 1 s scrape interval and its TSDB in a temporary directory.
Every wait has a deadline; Prometheus, ioportd and the simulator are killed at the end, always.

Usage: prometheus_test.py IOPORTD IOPORT_SIM [PROMETHEUS]
"""
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import unittest

IOPORTD, IOPORT_SIM = sys.argv[1], sys.argv[2]
PROMETHEUS = sys.argv[3] if len(sys.argv) > 3 else "/usr/bin/prometheus"
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))

from prometheus import Prometheus  # noqa: E402
from rig import Rig, die_with_parent, eventually  # noqa: E402

CONFIG = """modbus: {{ listen: "127.0.0.1:0" }}
http: {{ listen: "127.0.0.1:0" }}
links:
  - name: hub0
    protocol: ioport
    device: {hub_link}
    unit_id: 1
    timeout: 300ms
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0 }}
      - type: acm3p
        number: 0
        name: "boiler 1"
        channels:
          0: {{ name: "supply temperature", unit: "°C", scale: [0, 100, -20, 150] }}
"""


class ScrapedByPrometheus(unittest.TestCase):
    def setUp(self):
        """The simulator, ioportd and Prometheus, in a temporary directory."""
        self.dir = tempfile.mkdtemp(prefix="ioportd-prom-")
        self.rig = Rig(self.dir, IOPORTD, IOPORT_SIM, preexec_fn=die_with_parent)
        self.prometheus = None
        try:
            self.rig.start_hub("dim16:0,dom16:0,acm3p:0")
            self.rig.write_config(CONFIG.format(hub_link=self.rig.hub_link))
            self.rig.start_daemon()
            self.prometheus = Prometheus(PROMETHEUS, self.dir, self.rig.listening_port("HTTP"))
        except BaseException:
            self.stop_all()
            raise
        self.addCleanup(self.close)

    def stop_all(self):
        """Everything stopped, Prometheus first, and removed; ioportd's exit status on SIGTERM,
        or why there is none."""
        try:
            if self.prometheus:
                self.prometheus.stop()
            if self.rig.daemon:
                try:
                    return self.rig.stop_daemon(timeout=5)[1]
                except subprocess.TimeoutExpired:
                    return "still running 5 s after SIGTERM"
        finally:
            self.rig.close()
            shutil.rmtree(self.dir, ignore_errors=True)

    def close(self):
        log = self.logs()
        code = self.stop_all()
        self.assertEqual(code, 0, log)

    def logs(self):
        text = ""
        for path in (self.rig.log, self.prometheus.log if self.prometheus else None):
            if path and os.path.exists(path):
                with open(path) as f:
                    text += f"--- {os.path.basename(path)} ---\n{f.read()}"
        return text

    def value(self, expression):
        """The value of a query that has exactly one series, or None."""
        result = self.prometheus.query(expression)
        return result[0][1] if result and len(result) == 1 else None

    def test_prometheus_scrapes_ioportd_and_sees_an_input_change(self):
        rig, prometheus = self.rig, self.prometheus
        rig.ctl("set dim16:0 0x0000")
        # up is 1 only when every sample line parsed (Prometheus' scrape parser is lenient
        # about HELP and TYPE lines: http_test's promtool check covers those).
        eventually(lambda: self.value('up{job="ioportd"}') == 1, 15,
                   lambda: 'up{job="ioportd"} == 1: ' + prometheus.scrape_errors() + "\n"
                   + self.logs(), interval=0.2)
        self.assertGreater(self.value('scrape_samples_scraped{job="ioportd"}') or 0, 50)
        channel = 'ioportd_input_value{module="dim16 0",channel="3"}'
        eventually(lambda: self.value(channel) == 0, 10,
                   lambda: f"{channel} == 0: {prometheus.query(channel)}", interval=0.2)
        changed = time.monotonic()
        rig.ctl("set dim16:0 0x0008")
        eventually(lambda: self.value(channel) == 1, 10,
                   lambda: f"{channel} == 1: {prometheus.query(channel)}", interval=0.2)
        print(f"[ figure   ] the change was in Prometheus after "
              f"{time.monotonic() - changed:.1f} s (scrape interval 1 s)")
        self.assertEqual(self.value('ioportd_input_value{module="dim16 0",channel="2"}'), 0)
        self.assertEqual(self.value('ioportd_module_status{link="hub0",module="dim16 0"}'), 1)
        self.assertEqual(self.value('ioportd_module_status{link="hub0",module="dom16 0"}'), 1)
        self.assertEqual(self.value('ioportd_link_up{link="hub0"}'), 1)
        # A histogram Prometheus understands as one: a quantile can be computed from it.
        quantile = prometheus.query(
            "histogram_quantile(0.5, ioportd_modbus_request_duration_seconds_bucket)")
        self.assertIsNotNone(quantile)
        self.assertEqual(self.value('count(ioportd_build_info{job="ioportd"})'), 1)

    def test_prometheus_sees_scaled_values_with_their_names_and_units(self):
        """gateway.md §6.1: the engineering value, and names and units joined on by PromQL."""
        self.rig.ctl("set acm3p:0 13208 0 0")
        celsius = struct.unpack("<f", struct.pack("<f", -20 + 13208 / 65535 * 100 * 1.7))[0]
        value = 'ioportd_input_value{module="acm3p 0",channel="0"}'
        eventually(lambda: self.value(value) == celsius, 15,
                   lambda: f"{value} == {celsius}: {self.prometheus.query(value)}\n"
                   + self.prometheus.scrape_errors(), interval=0.2)
        info = 'ioportd_channel_info{name="supply temperature",unit="°C"}'
        self.assertEqual(self.value(info), 1)
        self.assertEqual(self.value('ioportd_module_info{module="acm3p 0",name="boiler 1"}'), 1)
        joined = self.prometheus.query(
            'ioportd_input_value * on(link, module, channel) group_left(name, unit) '
            'ioportd_channel_info{name="supply temperature"}')
        self.assertEqual(len(joined), 1, joined)
        labels, joined_value = joined[0]
        self.assertEqual((labels["name"], labels["unit"], labels["channel"]),
                         ("supply temperature", "°C", "0"))
        self.assertEqual(joined_value, celsius)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
