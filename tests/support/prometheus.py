"""A real Prometheus server (Debian's /usr/bin/prometheus) for the tests: on a free loopback
port, scraping one target every second, its TSDB in a directory of the test's.

    prometheus = Prometheus("/usr/bin/prometheus", directory, target_port,
                            scrape="    scheme: https\n    basic_auth: {...}\n")
    prometheus.query('up')     # [(labels, value)], or None while it is not answering
    prometheus.scrape_errors() # the targets' last errors, for a failure's message
    prometheus.stop()
"""
import json
import os
import subprocess
import urllib.error
import urllib.parse
import urllib.request

from rig import die_with_parent, free_port


class Prometheus:
    """Prometheus on a free loopback port scraping one target every second, its TSDB in
    `directory`; killed with the test process."""

    def __init__(self, binary, directory, target_port, scrape=""):
        """`scrape`: more keys of the job's scrape config (scheme, basic_auth, tls_config),
        indented as they go under it."""
        self.port = free_port()
        config = os.path.join(directory, "prometheus.yml")
        with open(config, "w") as f:
            f.write(f"""global:
  scrape_interval: 1s
  scrape_timeout: 900ms
  evaluation_interval: 1s
scrape_configs:
  - job_name: ioportd
    static_configs:
      - targets: ["127.0.0.1:{target_port}"]
{scrape}""")
        self.log = os.path.join(directory, "prometheus.log")
        with open(self.log, "w") as log:
            self.process = subprocess.Popen(
                [binary, f"--config.file={config}",
                 f"--storage.tsdb.path={os.path.join(directory, 'tsdb')}",
                 f"--web.listen-address=127.0.0.1:{self.port}",
                 "--log.level=warn"],
                stdout=log, stderr=log, preexec_fn=die_with_parent)

    def query(self, expression):
        """The instant vector of a PromQL query: [(labels, value)], or None if Prometheus is
        not answering (yet)."""
        url = (f"http://127.0.0.1:{self.port}/api/v1/query?"
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
                    f"http://127.0.0.1:{self.port}/api/v1/targets", timeout=2) as r:
                targets = json.load(r)["data"]["activeTargets"]
        except (urllib.error.URLError, ConnectionError, TimeoutError, KeyError) as e:
            return f"targets: {e}"
        return "; ".join(f"{t['scrapeUrl']}: health {t['health']}, last error "
                         f"'{t['lastError']}'" for t in targets)

    def stop(self, deadline=5):
        """SIGTERM, then SIGKILL if it is still there after `deadline`."""
        if self.process.poll() is not None:
            return
        self.process.terminate()
        try:
            self.process.wait(deadline)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(deadline)
