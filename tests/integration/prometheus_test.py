#!/usr/bin/python3
"""ioportd scraped by a real Prometheus server (Debian's /usr/bin/prometheus): the exposition of
/metrics is one that Prometheus ingests, and a change at a simulated device shows in its queries.

ioport-sim (a hub with dim16 0 and dom16 0) on a pty, ioportd on it with HTTP on a free loopback
port, Prometheus on another with a 1 s scrape interval and its TSDB in a temporary directory.
Every wait has a deadline; Prometheus, ioportd and the simulator are killed at the end, always.

Usage: prometheus_test.py IOPORTD IOPORT_SIM [PROMETHEUS]
"""
import ctypes
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import unittest
import urllib.error
import urllib.parse
import urllib.request

IOPORTD, IOPORT_SIM = sys.argv[1], sys.argv[2]
PROMETHEUS = sys.argv[3] if len(sys.argv) > 3 else "/usr/bin/prometheus"


def eventually(condition, deadline=5.0, interval=0.005):
    until = time.monotonic() + deadline
    while True:
        if condition():
            return True
        if time.monotonic() >= until:
            return False
        time.sleep(interval)


def die_with_parent():
    """In the child before exec: SIGKILL when the test process dies, even by SIGKILL (a CTest
    timeout), so that no Prometheus outlives the test."""
    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop(process, deadline=5):
    """SIGTERM, then SIGKILL if it is still there after `deadline`; its exit status."""
    if process is None or process.poll() is not None:
        return None if process is None else process.returncode
    process.terminate()
    try:
        return process.wait(deadline)
    except subprocess.TimeoutExpired:
        process.kill()
        return process.wait(deadline)


class Rig:
    """The simulator, ioportd and Prometheus, in a temporary directory."""

    def __init__(self):
        self.dir = tempfile.mkdtemp(prefix="ioportd-prom-")
        self.sim = self.daemon = self.prometheus = None
        try:
            self.start_sim()
            self.start_daemon()
            self.start_prometheus()
        except BaseException:
            self.close()
            raise

    def start_sim(self):
        self.link = os.path.join(self.dir, "ttyHUB")
        self.control = os.path.join(self.dir, "hub.ctl")
        self.sim = subprocess.Popen([IOPORT_SIM, "--link", self.link, "--control", self.control,
                                     "--no-line-timing", "--hub", "dim16:0,dom16:0"],
                                    stdout=subprocess.PIPE, text=True,
                                    preexec_fn=die_with_parent)
        banner = self.sim.stdout.readline()
        assert banner.startswith("ioport-sim: "), banner

    def start_daemon(self):
        config = os.path.join(self.dir, "ioportd.yaml")
        with open(config, "w") as f:
            f.write(f"""modbus: {{ listen: "127.0.0.1:0" }}
http: {{ listen: "127.0.0.1:0" }}
links:
  - name: hub0
    protocol: ioport
    device: {self.link}
    unit_id: 1
    timeout: 30ms
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0 }}
""")
        self.daemon_log = os.path.join(self.dir, "ioportd.log")
        with open(self.daemon_log, "w") as log:
            self.daemon = subprocess.Popen([IOPORTD, "--config", config], stdout=log, stderr=log,
                                           preexec_fn=die_with_parent)
        match = None

        def announced():
            nonlocal match
            with open(self.daemon_log) as f:
                match = re.search(r"HTTP on http://127\.0\.0\.1:(\d+)/", f.read())
            return match is not None or self.daemon.poll() is not None
        assert eventually(announced, 10) and match, self.log()
        self.http_port = int(match.group(1))

    def start_prometheus(self):
        self.prometheus_port = free_port()
        config = os.path.join(self.dir, "prometheus.yml")
        with open(config, "w") as f:
            f.write(f"""global:
  scrape_interval: 1s
  scrape_timeout: 900ms
  evaluation_interval: 1s
scrape_configs:
  - job_name: ioportd
    static_configs:
      - targets: ["127.0.0.1:{self.http_port}"]
""")
        self.prometheus_log = os.path.join(self.dir, "prometheus.log")
        with open(self.prometheus_log, "w") as log:
            self.prometheus = subprocess.Popen(
                [PROMETHEUS, f"--config.file={config}",
                 f"--storage.tsdb.path={os.path.join(self.dir, 'tsdb')}",
                 f"--web.listen-address=127.0.0.1:{self.prometheus_port}",
                 "--log.level=warn"],
                stdout=log, stderr=log, preexec_fn=die_with_parent)

    def query(self, expression):
        """The instant vector of a PromQL query: [(labels, value)], or None if Prometheus is
        not answering (yet)."""
        url = (f"http://127.0.0.1:{self.prometheus_port}/api/v1/query?"
               + urllib.parse.urlencode({"query": expression}))
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                reply = json.load(response)
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            return None
        if reply.get("status") != "success":
            return None
        return [(r["metric"], float(r["value"][1])) for r in reply["data"]["result"]]

    def scrape_errors(self):
        """Prometheus' last scrape error of each target, for a failure's message."""
        try:
            with urllib.request.urlopen(
                    f"http://127.0.0.1:{self.prometheus_port}/api/v1/targets", timeout=2) as r:
                targets = json.load(r)["data"]["activeTargets"]
        except (urllib.error.URLError, ConnectionError, TimeoutError, KeyError) as e:
            return f"targets: {e}"
        return "; ".join(f"{t['scrapeUrl']}: health {t['health']}, last error "
                         f"'{t['lastError']}'" for t in targets)

    def ctl(self, command):
        out = subprocess.run([IOPORT_SIM, "ctl", self.control, *command.split()],
                             capture_output=True, text=True, timeout=10)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    def log(self):
        text = ""
        for name in ("daemon_log", "prometheus_log"):
            path = getattr(self, name, None)
            if path and os.path.exists(path):
                with open(path) as f:
                    text += f"--- {os.path.basename(path)} ---\n{f.read()}"
        return text

    def close(self):
        """Everything stopped, Prometheus first; ioportd's exit status."""
        stop(self.prometheus)
        code = stop(self.daemon)
        stop(self.sim)
        shutil.rmtree(self.dir, ignore_errors=True)
        return code


class ScrapedByPrometheus(unittest.TestCase):
    def setUp(self):
        self.rig = Rig()
        self.addCleanup(self.close)

    def close(self):
        log = self.rig.log()
        code = self.rig.close()
        self.assertEqual(code, 0, log)

    def value(self, expression):
        """The value of a query that has exactly one series, or None."""
        result = self.rig.query(expression)
        return result[0][1] if result and len(result) == 1 else None

    def test_prometheus_scrapes_ioportd_and_sees_an_input_change(self):
        rig = self.rig
        rig.ctl("set dim16:0 0x0000")
        # up is 1 only when every sample line parsed (Prometheus' scrape parser is lenient
        # about HELP and TYPE lines: http_test's promtool check covers those).
        self.assertTrue(eventually(lambda: self.value('up{job="ioportd"}') == 1, 15, 0.2),
                        rig.scrape_errors() + "\n" + rig.log())
        self.assertGreater(self.value('scrape_samples_scraped{job="ioportd"}') or 0, 50)
        channel = 'ioportd_input_value{module="dim16 0",channel="3"}'
        self.assertTrue(eventually(lambda: self.value(channel) == 0, 10, 0.2),
                        rig.query(channel))
        changed = time.monotonic()
        rig.ctl("set dim16:0 0x0008")
        self.assertTrue(eventually(lambda: self.value(channel) == 1, 10, 0.2),
                        rig.query(channel))
        print(f"[ figure   ] the change was in Prometheus after "
              f"{time.monotonic() - changed:.1f} s (scrape interval 1 s)")
        self.assertEqual(self.value('ioportd_input_value{module="dim16 0",channel="2"}'), 0)
        self.assertEqual(self.value('ioportd_module_status{link="hub0",module="dim16 0"}'), 1)
        self.assertEqual(self.value('ioportd_module_status{link="hub0",module="dom16 0"}'), 1)
        self.assertEqual(self.value('ioportd_link_up{link="hub0"}'), 1)
        # A histogram Prometheus understands as one: a quantile can be computed from it.
        quantile = rig.query(
            "histogram_quantile(0.5, ioportd_modbus_request_duration_seconds_bucket)")
        self.assertIsNotNone(quantile)
        self.assertEqual(self.value('count(ioportd_build_info{job="ioportd"})'), 1)


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
