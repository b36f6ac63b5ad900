#!/usr/bin/python3
"""Operators on the web (gateway.md §7.1), against the real daemon on the simulator: the
exporter-toolkit's web configuration with bcrypt passwords made by htpasswd, the failure
limiter seen from two loopback addresses, POST /api/v1/write answer by answer, TLS with client
certificates whose CN is the user, a reload of the web file, and a real Prometheus scraping
/metrics over HTTPS with basic_auth and tls_config.

Usage: web_test.py IOPORTD IOPORT_SIM PROMETHEUS [TEST ...]
"""
import base64
import concurrent.futures
import http.client
import json
import os
import re
import shutil
import socket
import ssl
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import unittest

IOPORTD, IOPORT_SIM, PROMETHEUS = sys.argv[1:4]
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))

from certificates import Certificates  # noqa: E402
from prometheus import Prometheus  # noqa: E402
from rig import SLOWDOWN, Rig, die_with_parent, eventually  # noqa: E402

CONFIG = """modbus: {{ listen: "127.0.0.1:0", read_only: {read_only} }}
http:
  listen: "127.0.0.1:0"
  web_config_file: {web}
  operators: [{operators}]
links:
  - name: hub0
    protocol: ioport
    device: {hub_link}
    unit_id: 1
    timeout: 300ms
    retries: 0
    max_pending_writes: 1
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0 }}
      - {{ type: rgbdm, number: 0 }}
"""
SECURITY_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'",
}


def htpasswd(user, password):
    """A bcrypt hash as the docs make one (htpasswd -nBC; cost 5 here, for the tests' speed)."""
    out = subprocess.run(["htpasswd", "-nbBC", "5", user, password], capture_output=True,
                         text=True, check=True, timeout=30).stdout
    return out.strip().split(":", 1)[1]


def basic(user, password):
    return "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()


def write_private(path, text):
    """A file only its owner reads: the web configuration grants rights (gateway.md §5.6)."""
    if os.path.exists(path):
        os.unlink(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


class Reply:
    def __init__(self, response):
        self.status = response.status
        self.headers = response.headers
        self.body = response.read().decode()

    def json(self):
        return json.loads(self.body)


class WebRig(unittest.TestCase):
    """The simulator (dim16 0, dom16 0, rgbdm 0) and ioportd with a web configuration."""
    web_text = ""
    operators = "alice"

    @classmethod
    def setUpClass(cls):
        cls.hashes = {"alice": htpasswd("alice", "alice-pw"), "bob": htpasswd("bob", "bob-pw")}

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="ioportd-web-")
        self.addCleanup(shutil.rmtree, self.dir, ignore_errors=True)
        self.web = os.path.join(self.dir, "web.yml")
        self.rig = Rig(self.dir, IOPORTD, IOPORT_SIM, preexec_fn=die_with_parent)
        self.addCleanup(self.rig.close)
        self.rig.start_hub("dim16:0,dom16:0,rgbdm:0")
        write_private(self.web, self.web_config())
        self.rig.write_config(self.config())
        self.rig.start_daemon()
        self.port = self.rig.listening_port("HTTP")

    def web_config(self):
        return "basic_auth_users:\n" + "".join(f"  {u}: {h}\n" for u, h in self.hashes.items())

    def config(self, read_only="false"):
        return CONFIG.format(read_only=read_only, web=self.web, operators=self.operators,
                             hub_link=self.rig.hub_link)

    def connection(self, source="127.0.0.1"):
        return http.client.HTTPConnection("127.0.0.1", self.port, timeout=10,
                                          source_address=(source, 0))

    def request(self, method, path, auth=None, body=None, headers=None, source="127.0.0.1",
                connection=None):
        c = connection or self.connection(source)
        all_headers = dict(headers or {})
        if auth:
            all_headers["Authorization"] = basic(*auth)
        c.request(method, path, body=body, headers=all_headers)
        reply = Reply(c.getresponse())
        if connection is None:
            c.close()
        return reply

    def write(self, point, value, auth=("alice", "alice-pw"), module="dom16_0", link="hub0",
              headers=None, **kwargs):
        body = json.dumps({"link": link, "module": module, "point": point, "value": value})
        return self.request("POST", "/api/v1/write", auth, body,
                            {"Content-Type": "application/json", **(headers or {})}, **kwargs)

    def outputs(self):
        return int(self.rig.ctl("get dom16:0"), 0)


class Passwords(WebRig):
    def test_every_path_needs_a_user_and_every_answer_has_the_security_headers(self):
        for path in ("/", "/metrics", "/api/v1/state", "/api/v1/trends", "/healthz", "/map",
                     "/nonexistent"):
            with self.subTest(path=path):
                refused = self.request("GET", path)
                self.assertEqual(refused.status, 401, refused.body)
                self.assertEqual(refused.headers["WWW-Authenticate"],
                                 'Basic realm="ioportd", charset="UTF-8"')
                for name, value in SECURITY_HEADERS.items():
                    self.assertEqual(refused.headers[name], value)
                served = self.request("GET", path, ("bob", "bob-pw"))
                # /healthz is 503 until every module was polled once: served all the same.
                self.assertIn(served.status, {"/nonexistent": (404,), "/healthz": (200, 503)}
                              .get(path, (200,)), served.body)
                for name, value in SECURITY_HEADERS.items():
                    self.assertEqual(served.headers[name], value)
        self.assertEqual(self.request("GET", "/", ("bob", "wrong")).status, 401)
        # Who the page is for: the state names the user and whether it may write.
        state = self.request("GET", "/api/v1/state", ("bob", "bob-pw")).json()
        self.assertEqual(state["user"], {"name": "bob", "operator": False})
        state = self.request("GET", "/api/v1/state", ("alice", "alice-pw")).json()
        self.assertEqual(state["user"], {"name": "alice", "operator": True})

    def test_five_failures_a_minute_limit_that_address_alone(self):
        for i in range(5):
            self.assertEqual(self.request("GET", "/metrics", ("bob", f"guess{i}")).status, 401)
        limited = self.request("GET", "/metrics", ("bob", "bob-pw"))
        self.assertEqual(limited.status, 429, limited.body)
        self.assertGreaterEqual(int(limited.headers["Retry-After"]), 50)
        self.assertLessEqual(int(limited.headers["Retry-After"]), 60)
        # Another address is served meanwhile, and sees the failures counted.
        other = self.request("GET", "/metrics", ("bob", "bob-pw"), source="127.0.0.2")
        self.assertEqual(other.status, 200)
        self.assertRegex(other.body, r"(?m)^ioportd_http_auth_failures_total 5$")
        # Logged through the limiter: the first failure, not five lines.
        self.rig.wait_log(r"HTTP: authentication failed for user 'bob' from 127\.0\.0\.1 "
                          r"\(logged once a minute per address\)")
        self.assertEqual(len(re.findall(r"authentication failed", self.rig.log_text())), 1)

    def test_a_reload_takes_the_new_passwords(self):
        # /metrics, not /healthz: its answer does not wait for the first poll of every module.
        self.assertEqual(self.request("GET", "/metrics", ("bob", "bob-pw")).status, 200)
        self.hashes = {"alice": self.hashes["alice"], "bob": htpasswd("bob", "new-pw")}
        write_private(self.web, self.web_config())
        log = self.rig.reload(self.config())
        self.assertIn("reloaded", log)
        self.assertEqual(self.request("GET", "/metrics", ("bob", "bob-pw")).status, 401)
        self.assertEqual(self.request("GET", "/metrics", ("bob", "new-pw")).status, 200)
        # A web file others could change is refused, and the running configuration kept.
        os.chmod(self.web, 0o666)
        log = self.rig.reload(self.config())
        self.assertRegex(log, r"web\.yml is writable by every user")
        self.assertEqual(self.request("GET", "/metrics", ("bob", "new-pw")).status, 200)
        # So is one that another user owns (gateway.md §7.5), who could make themselves an operator.
        if os.geteuid() == 0:
            os.chmod(self.web, 0o600)
            os.chown(self.web, 65534, -1)
            log = self.rig.reload(self.config())
            self.assertRegex(log, r"web\.yml is owned by nobody \(uid 65534\), neither root nor")
            self.assertEqual(self.request("GET", "/metrics", ("bob", "new-pw")).status, 200)


class Writes(WebRig):
    def test_an_operator_writes_and_the_device_confirms_it(self):
        reply = self.write("out3", "ON")
        self.assertEqual((reply.status, reply.json()), (200, {"result": "confirmed"}))
        self.assertTrue(self.outputs() & 0x0008)
        self.rig.wait_log(r"write by http alice@127\.0\.0\.1 to unit 1")
        reply = self.write("out3", False)
        self.assertEqual(reply.status, 200, reply.body)
        self.assertFalse(self.outputs() & 0x0008)
        reply = self.write("colour", "red", module="rgbdm_0")
        self.assertEqual(reply.status, 200, reply.body)
        # Same origin, as the page sends it.
        reply = self.write("out4", "ON", headers={"Origin": f"http://127.0.0.1:{self.port}"})
        self.assertEqual(reply.status, 200, reply.body)

    def test_a_client_that_expects_100_continue_is_told_to_go_on_then_answered(self):
        body = json.dumps({"link": "hub0", "module": "dom16_0", "point": "out5", "value": "ON"})
        head = (f"POST /api/v1/write HTTP/1.1\r\nHost: 127.0.0.1:{self.port}\r\n"
                f"Authorization: {basic('alice', 'alice-pw')}\r\n"
                f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
                "Expect: 100-continue\r\nConnection: close\r\n\r\n")

        def answer(s):
            received = b""
            while b"\r\n\r\n" not in received:
                chunk = s.recv(4096)
                self.assertTrue(chunk, received)
                received += chunk
            return received
        with socket.create_connection(("127.0.0.1", self.port), timeout=10) as s:
            s.sendall(head.encode())
            self.assertEqual(answer(s), b"HTTP/1.1 100 Continue\r\n\r\n")
            s.sendall(body.encode())
            received = answer(s)
            while chunk := s.recv(4096):
                received += chunk
        self.assertTrue(received.startswith(b"HTTP/1.1 200 OK\r\n"), received)
        self.assertTrue(received.endswith(b'\r\n\r\n{"result":"confirmed"}\n'), received)
        self.assertTrue(self.outputs() & 0x0020)

    def refused(self, reply, status, result, error=""):
        self.assertEqual(reply.status, status, reply.body)
        answer = reply.json()
        self.assertEqual(answer["result"], result, answer)
        self.assertIn(error, answer.get("error", ""))
        return answer

    def test_every_refusal_answers_with_its_status_and_word_and_writes_nothing(self):
        before = self.outputs()
        self.refused(self.write("out3", "ON", auth=None), 401, "unauthorized")
        self.refused(self.write("out3", "ON", auth=("alice", "x")), 401, "unauthorized")
        self.refused(self.write("out3", "ON", auth=("bob", "bob-pw")), 403, "forbidden",
                     "is not one of http.operators")
        self.refused(self.write("out3", "ON", headers={"Origin": "http://evil.example"}), 403,
                     "forbidden", "a page of another origin (http://evil.example)")
        self.refused(self.write("out3", "ON", headers={"Origin": "null"}), 403, "forbidden")
        self.refused(self.write("out3", "ON", headers={"Content-Type": "text/plain"}), 415,
                     "unsupported_media_type")
        self.refused(self.write("out3", "ON", headers={
            "Content-Type": "application/x-www-form-urlencoded"}), 415, "unsupported_media_type")
        self.refused(self.write("out3", "maybe"), 400, "invalid_value")
        self.refused(self.write("out99", "ON"), 404, "not_found", "no point 'out99'")
        self.refused(self.write("out3", "ON", module="dom16_7"), 404, "not_found")
        self.refused(self.write("out3", "ON", link="hub9"), 404, "not_found", "no link")
        body = self.request("POST", "/api/v1/write", ("alice", "alice-pw"), "{not json",
                            {"Content-Type": "application/json"})
        self.refused(body, 400, "bad_request")
        large = self.request("POST", "/api/v1/write", ("alice", "alice-pw"), "x" * 2000,
                             {"Content-Type": "application/json"})
        self.refused(large, 413, "too_large")
        get = self.request("GET", "/api/v1/write", ("alice", "alice-pw"))
        self.assertEqual((get.status, get.headers["Allow"]), (405, "POST"))
        self.assertEqual(self.outputs(), before)
        # Refusals are logged through the limiter, with who asked.
        self.rig.wait_log(r"HTTP write by http alice@127\.0\.0\.1 refused \(not_found\)")

    def test_a_silent_module_is_504_and_a_full_queue_503(self):
        self.rig.ctl("fault dom16:0 silent")
        self.refused(self.write("out3", "ON"), 504, "no_answer")
        # max_pending_writes 1: of writes arriving together, one runs, one waits, others are
        # refused at once.
        with concurrent.futures.ThreadPoolExecutor(6) as pool:
            replies = list(pool.map(lambda i: self.write(f"out{i}", "ON"), range(6)))
        statuses = sorted(r.status for r in replies)
        self.assertIn(503, statuses, [r.body for r in replies])
        busy = next(r for r in replies if r.status == 503)
        self.refused(busy, 503, "busy")
        self.assertEqual(busy.headers["Retry-After"], "1")

    def test_read_only_refuses_every_write(self):
        log = self.rig.reload(self.config(read_only="true"))
        self.assertIn("reloaded", log)
        self.refused(self.write("out3", "ON"), 403, "forbidden", "read_only")
        self.assertFalse(self.outputs() & 0x0008)


class ClientCertificates(WebRig):
    """TLS only, client certificates required and verified, no passwords: the CN is the user."""
    operators = "operator-1"

    def web_config(self):
        self.certs = Certificates(self.dir)
        self.certs.client("operator", None)
        self.certs.client("viewer", None)
        return ("tls_server_config:\n  cert_file: server.pem\n  key_file: server.key\n"
                "  client_ca_file: ca.pem\n  client_auth_type: RequireAndVerifyClientCert\n"
                "http_server_config:\n  headers:\n"
                "    Strict-Transport-Security: max-age=31536000\n")

    def tls(self, who):
        context = ssl.create_default_context(cafile=self.certs.path("ca.pem"))
        if who:
            context.load_cert_chain(self.certs.path(f"{who}.pem"), self.certs.path(f"{who}.key"))
        return http.client.HTTPSConnection("127.0.0.1", self.port, timeout=10, context=context)

    def test_the_port_speaks_tls_only_and_the_certificates_cn_is_the_user(self):
        self.rig.wait_log(r"HTTP on https://127\.0\.0\.1:\d+/")
        # Plain HTTP gets no answer but the closed connection.
        with socket.create_connection(("127.0.0.1", self.port), timeout=10) as s:
            s.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            self.assertNotIn(b"HTTP/1.1 200", s.recv(4096))
        # No certificate: refused in the handshake (TLS 1.3 tells at the first read).
        with self.assertRaises((ssl.SSLError, ConnectionError)):
            self.request("GET", "/healthz", connection=self.tls(None))
        served = self.request("GET", "/api/v1/state", connection=self.tls("operator"))
        self.assertEqual(served.status, 200)
        self.assertEqual(served.headers["Strict-Transport-Security"], "max-age=31536000")
        self.assertEqual(served.json()["user"], {"name": "operator-1", "operator": True})
        reply = self.write("out3", "ON", auth=None, connection=self.tls("operator"))
        self.assertEqual(reply.status, 200, reply.body)
        self.assertTrue(self.outputs() & 0x0008)
        self.rig.wait_log(r"write by http operator-1@127\.0\.0\.1 to unit 1")
        viewer = self.write("out3", "OFF", auth=None, connection=self.tls("viewer"))
        self.assertEqual(viewer.status, 403, viewer.body)

    def test_connections_that_never_start_tls_keep_no_one_out(self):
        """gateway.md §7.5: handshakes have a budget per address, and never take the places of
        connections being served."""
        silent = []
        for _ in range(64):
            s = socket.socket()
            s.bind(("127.0.0.7", 0))
            s.settimeout(10)
            try:
                s.connect(("127.0.0.1", self.port))
            except OSError:
                s.close()
                continue
            silent.append(s)
        self.addCleanup(lambda: [s.close() for s in silent])
        for _ in range(3):
            served = self.request("GET", "/api/v1/state", connection=self.tls("operator"))
            self.assertEqual(served.status, 200)
        text = self.request("GET", "/metrics", connection=self.tls("viewer")).body
        # Four handshakes of that address at once; the other sixty closed at accept.
        self.assertGreaterEqual(metric(text, 'ioportd_http_connections_refused_total'
                                             '{reason="too_many_handshakes"}'), 60)

    def test_prometheus_scrapes_over_https_with_its_client_certificate(self):
        prometheus = Prometheus(PROMETHEUS, self.dir, self.port, scrape=(
            "    scheme: https\n    tls_config:\n"
            f"      ca_file: {self.certs.path('ca.pem')}\n"
            f"      cert_file: {self.certs.path('viewer.pem')}\n"
            f"      key_file: {self.certs.path('viewer.key')}\n"
            "      server_name: localhost\n"))
        self.addCleanup(prometheus.stop)
        eventually(lambda: prometheus.query('up{job="ioportd"} == 1'), 30,
                   prometheus.scrape_errors)


def metric(rig_text, name):
    match = re.search(rf"(?m)^{re.escape(name)} (\S+)$", rig_text)
    return float(match.group(1)) if match else None


class Limits(WebRig):
    """gateway.md §7.5 against the real daemon: what one address, or many, can do to sign-in.
    Hashes of cost 10, as htpasswd -nBC 10 makes them and docs/http.md says to."""
    users = ["alice", "bob", "prom", "u1", "u2", "u3", "u4", "u5"]

    @classmethod
    def setUpClass(cls):
        def cost10(user):
            out = subprocess.run(["htpasswd", "-nbBC", "10", user, f"{user}-pw"],
                                 capture_output=True, text=True, check=True, timeout=30).stdout
            return user, out.strip().split(":", 1)[1]
        with concurrent.futures.ThreadPoolExecutor(4) as pool:
            cls.hashes = dict(pool.map(cost10, cls.users))

    def scrape(self):
        """/metrics as prom from 127.0.0.1, whose password is remembered after the first time."""
        reply = self.request("GET", "/metrics", ("prom", "prom-pw"))
        self.assertEqual(reply.status, 200, reply.body)
        return reply.body

    def test_a_burst_from_one_address_is_one_check_and_five_a_minute_is_all(self):
        before = metric(self.scrape(), "ioportd_http_auth_failures_total")
        # Eight connections, the most one address may hold, two requests each.
        connections = [self.connection("127.0.0.9") for _ in range(8)]
        for c in connections:
            c.connect()
        barrier = threading.Barrier(len(connections))

        def attempts(c):
            barrier.wait(timeout=10)
            return [self.request("GET", "/metrics", ("bob", f"guess{i}"), connection=c).status
                    for i in range(2)]
        with concurrent.futures.ThreadPoolExecutor(len(connections)) as pool:
            burst = sum(pool.map(attempts, connections), [])
        for c in connections:
            c.close()
        # One at a time: all but the checks that fit (one, or more on a machine too slow to send
        # the burst within one bcrypt) are 429 at once.
        self.assertGreaterEqual(burst.count(429), 11, burst)
        self.assertEqual(burst.count(401) + burst.count(429), 16, burst)
        later = [self.request("GET", "/metrics", ("bob", f"guess{i}"), source="127.0.0.9").status
                 for i in range(8)]
        self.assertEqual(burst.count(401) + later.count(401), 5, (burst, later))
        limited = self.request("GET", "/metrics", ("bob", "bob-pw"), source="127.0.0.9")
        self.assertEqual(limited.status, 429)
        text = self.scrape()
        self.assertEqual(metric(text, "ioportd_http_auth_failures_total") - before, 5)
        self.assertGreaterEqual(
            metric(text, 'ioportd_http_auth_refused_total{reason="limited"}'), 11 + 3 + 1)

    def test_users_sign_in_while_130_addresses_attack(self):
        self.scrape()  # prom is remembered: its scrapes cost no check from here on
        attackers = [f"127.0.1.{i}" for i in range(1, 131)]
        stop = threading.Event()
        counter = iter(range(10**9))
        attacked = {"requests": 0}

        def attack():
            deadline = time.monotonic() + 120 * SLOWDOWN
            while not stop.is_set() and time.monotonic() < deadline:
                source = attackers[next(counter) % len(attackers)]
                try:
                    self.request("GET", "/metrics", ("mallory", "guess"), source=source)
                    attacked["requests"] += 1
                except OSError:
                    pass
        pool = concurrent.futures.ThreadPoolExecutor(24)
        workers = [pool.submit(attack) for _ in range(24)]
        self.addCleanup(pool.shutdown)
        self.addCleanup(stop.set)
        # Every attacking address has failed: all 130 are behind whoever has not.
        eventually(lambda: metric(self.scrape(), "ioportd_http_auth_failures_total") >= 130, 90,
                   "130 addresses failed once", interval=0.5)
        times = []
        for i in range(1, 6):
            started = time.monotonic()
            reply = self.request("GET", "/api/v1/state", (f"u{i}", f"u{i}-pw"),
                                 source=f"127.0.0.{10 + i}")
            times.append(time.monotonic() - started)
            self.assertEqual(reply.status, 200, reply.body)
            self.assertEqual(reply.json()["user"]["name"], f"u{i}")
        stop.set()
        for worker in workers:
            worker.result(timeout=30)
        text = self.scrape()
        failures = metric(text, "ioportd_http_auth_failures_total")
        limited = metric(text, 'ioportd_http_auth_refused_total{reason="limited"}')
        busy = metric(text, 'ioportd_http_auth_refused_total{reason="busy"}')
        print(f"[ figure ] 5 of 5 users signed in under an attack from 130 addresses "
              f"({attacked['requests']} requests), slowest {max(times) * 1000:.0f} ms; "
              f"failures {failures:.0f}, 429 {limited:.0f}, 503 {busy:.0f}")
        self.assertLess(max(times), 5 * SLOWDOWN)


class Timing(WebRig):
    """gateway.md §7.5: an unknown user costs what a known user's wrong password costs."""

    @classmethod
    def setUpClass(cls):
        out = subprocess.run(["htpasswd", "-nbBC", "12", "alice", "alice-pw"], capture_output=True,
                             text=True, check=True, timeout=30).stdout
        cls.hashes = {"alice": out.strip().split(":", 1)[1]}

    def test_refusing_an_unknown_user_takes_as_long_as_a_wrong_password(self):
        def refusal(user, source):
            started = time.monotonic()
            self.assertEqual(self.request("GET", "/metrics", (user, "wrong"),
                                          source=source).status, 401)
            return time.monotonic() - started
        known, unknown = [], []
        for i in range(5):  # alternately, each from an address of its own
            known.append(refusal("alice", f"127.0.2.{2 * i + 1}"))
            unknown.append(refusal("nobody-here", f"127.0.2.{2 * i + 2}"))
        ratio = statistics.median(unknown) / statistics.median(known)
        print(f"[ figure ] refusal at cost 12: known user {statistics.median(known) * 1000:.0f} "
              f"ms, unknown user {statistics.median(unknown) * 1000:.0f} ms (median of 5)")
        # The decoy of cost 10 took a quarter of cost 12's time.
        self.assertGreater(ratio, 0.6, (known, unknown))
        self.assertLess(ratio, 1.6, (known, unknown))


class PrometheusWithPasswords(WebRig):
    def test_prometheus_scrapes_with_basic_auth_and_is_down_with_a_wrong_password(self):
        good = Prometheus(PROMETHEUS, self.dir, self.port, scrape=(
            "    basic_auth: { username: bob, password: bob-pw }\n"))
        self.addCleanup(good.stop)
        eventually(lambda: good.query('up{job="ioportd"} == 1'), 30, good.scrape_errors)
        good.stop()
        os.mkdir(os.path.join(self.dir, "bad"))
        bad = Prometheus(PROMETHEUS, os.path.join(self.dir, "bad"), self.port, scrape=(
            "    basic_auth: { username: bob, password: wrong }\n"))
        self.addCleanup(bad.stop)
        # Prometheus shows a scrape's error before it commits that scrape's `up`: wait for both.
        eventually(lambda: bad.query('up{job="ioportd"} == 0'), 30, bad.scrape_errors)
        self.assertIn("401", bad.scrape_errors())


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1] + sys.argv[4:], verbosity=2)
