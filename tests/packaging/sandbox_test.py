#!/usr/bin/python3
"""ioportd stays inside the sandbox of its systemd unit.

The unit's SystemCallFilter= answers EPERM to any call outside the set, and
RestrictAddressFamilies= refuses other socket families; ProtectSystem=strict makes every file
read-only. A change to the daemon that needs more would pass every other test and fail only in
production. So this test runs the real daemon against the simulator under strace, as systemd
would run it (NOTIFY_SOCKET, WATCHDOG_USEC): start-up, Modbus reads and writes on two units,
Modbus/TCP Security (TLS handshakes, full and resumed, and a request), a port unplugged and back,
the watchdog, and SIGTERM; and checks every system call it made
against the unit's filter, as systemd-analyze expands it, every socket family against the
unit's list, that it opened nothing for writing but its serial ports, and that it looked at
nothing that ProcSubset=pid and ProtectHome=yes hide.

Usage: sandbox_test.py IOPORTD IOPORT_SIM UNIT_FILE
"""

import os
import re
import signal
import socket
import ssl
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from unit_file import unit_settings

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "support"))
from certificates import Certificates  # noqa: E402

IOPORTD, IOPORT_SIM, UNIT_FILE = sys.argv[1], sys.argv[2], Path(sys.argv[3])

failures: list[str] = []
# Calls whose first argument is a path (after AT_FDCWD where they take a directory).
PATH_CALLS = {"open", "openat", "openat2", "stat", "lstat", "newfstatat", "statx", "access",
              "faccessat", "faccessat2", "readlink", "readlinkat"}
# ProcSubset=pid leaves only /proc/PID (and /proc/self) visible; ProtectHome=yes empties these.
HIDDEN_PATHS = r"/proc/(?!self/|self$|thread-self|\d+(/|$))|/home(/|$)|/root(/|$)|/run/user(/|$)"


def check(condition: bool, message: str) -> bool:
    if not condition:
        failures.append(message)
        print(f"FAIL: {message}", flush=True)
    return condition


def expand(names: list[str]) -> set[str]:
    """System calls of the given calls and @groups, as this systemd knows them."""
    calls: set[str] = set()
    for name in names:
        if not name.startswith("@"):
            calls.add(name)
            continue
        listing = subprocess.run(["systemd-analyze", "syscall-filter", name],
                                 capture_output=True, text=True, check=True).stdout
        members = [l.strip() for l in listing.splitlines()[1:]]
        calls |= expand([m for m in members if m and not m.startswith("#")])
    return calls


def allowed_calls(filters: list[str]) -> set[str]:
    """SystemCallFilter= lines as systemd.exec(5) combines them: the first line decides
    between an allow list and a deny list ("~"); later lines add to or take from it."""
    assert filters and not filters[0].startswith("~"), "the unit must have an allow list"
    allowed: set[str] = set()
    for line in filters:
        if line.startswith("~"):
            allowed -= expand(line[1:].split())
        else:
            allowed |= expand(line.split())
    return allowed


def modbus(port: int, unit: int, pdu: bytes, transaction: int) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu)
        header = s.recv(7, socket.MSG_WAITALL)
        length = struct.unpack(">H", header[4:6])[0]
        return s.recv(length - 1, socket.MSG_WAITALL)


def modbus_tls(port: int, context: ssl.SSLContext, session=None):
    """A read of unit 1 over TLS: the answer, whether the session was resumed, the session."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as raw:
        with context.wrap_socket(raw, server_hostname="127.0.0.1", session=session) as s:
            s.sendall(struct.pack(">HHHB", 9, 0, 6, 1) + struct.pack(">BHH", 4, 0, 1))
            answer = b""
            while len(answer) < 11:
                chunk = s.recv(11 - len(answer))
                if not chunk:
                    break
                answer += chunk
            return answer[7:], s.session_reused, s.session


class Notifications:
    """The NOTIFY_SOCKET that systemd would give the service."""

    def __init__(self, path: str):
        self.path = path
        self.socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.socket.bind(path)
        self.messages: list[str] = []

    def wait_for(self, predicate, deadline: float) -> bool:
        until = time.monotonic() + deadline
        while not any(predicate(m) for m in self.messages):
            remaining = until - time.monotonic()
            if remaining <= 0:
                return False
            self.socket.settimeout(remaining)
            try:
                self.messages += self.socket.recv(4096).decode().split("\n")
            except TimeoutError:
                return False
        return True


def main() -> int:
    settings = unit_settings(UNIT_FILE)
    allowed = allowed_calls(settings.get("SystemCallFilter", []))
    families = set(" ".join(settings.get("RestrictAddressFamilies", [])).split())
    check(bool(families) and not any(f.startswith("~") for f in families),
          f"RestrictAddressFamilies= is not an allow list: {families}")

    with tempfile.TemporaryDirectory(prefix="ioportd-sandbox-") as scratch:
        hub, id2 = f"{scratch}/ttyHUB", f"{scratch}/ttyID2"
        sims = [subprocess.Popen([IOPORT_SIM, "--link", hub, "--control", f"{scratch}/hub.ctl",
                                  "--no-line-timing", "--hub", "dim16:0,dom16:0,acm3p:0"],
                                 stdout=subprocess.PIPE, text=True),
                subprocess.Popen([IOPORT_SIM, "--link", id2, "--id2", "--no-line-timing"],
                                 stdout=subprocess.PIPE, text=True)]
        daemon = None
        try:
            for sim in sims:
                banner = sim.stdout.readline()
                assert banner.startswith("ioport-sim: "), banner
            certs = Certificates(scratch)
            certs.client("operator", "operator")
            config = Path(scratch, "ioportd.yaml")
            config.write_text(f"""modbus:
  listen: "127.0.0.1:0"
  tls:
    listen: "127.0.0.1:0"
    certificate: {scratch}/server.pem
    key: {scratch}/server.key
    client_ca: {scratch}/ca.pem
    roles:
      operator: {{ units: all, access: read_write }}
http:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {hub}
    timeout: 500ms
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0 }}
      - {{ type: acm3p, number: 0 }}
  - name: press
    protocol: id2
    device: {id2}
    timeout: 500ms
""")
            notify = Notifications(f"{scratch}/notify")
            trace, log = f"{scratch}/trace", f"{scratch}/ioportd.log"
            env = dict(os.environ, NOTIFY_SOCKET=notify.path, WATCHDOG_USEC="400000")
            if "ASAN_OPTIONS" in env:
                # The sanitizer build: LeakSanitizer cannot work under ptrace, and would write
                # a report saying so. ASan and UBSan still check everything else.
                env["ASAN_OPTIONS"] += ":detect_leaks=0"
            with open(log, "w") as log_file:
                daemon = subprocess.Popen(
                    ["strace", "-f", "-qq", "-o", trace, IOPORTD, "--config", str(config)],
                    env=env, stdout=log_file, stderr=log_file)
            if not check(notify.wait_for(lambda m: m == "READY=1", 15),
                         f"no READY=1:\n{Path(log).read_text()}"):
                return 1
            port = int(re.search(r"Modbus TCP on 127\.0\.0\.1:(\d+)",
                                 Path(log).read_text()).group(1))
            check(notify.wait_for(lambda m: "2 of 2 links up, 4 of 4 modules online" in m, 10),
                  f"the modules did not come online: {notify.messages}")

            answers = [
                modbus(port, 1, struct.pack(">BHH", 4, 0, 4), 1),        # dim16, acm3p raw
                modbus(port, 1, struct.pack(">BHH", 5, 0, 0xFF00), 2),   # dom16 o0 on
                modbus(port, 1, struct.pack(">BHH", 4, 1000, 10), 3),    # diagnostics
                modbus(port, 2, struct.pack(">BHH", 4, 0, 1), 4),        # ID-2 counter
            ]
            for answer in answers:
                check(answer[0] < 0x80, f"Modbus exception {answer.hex()}")
            # Modbus/TCP Security: OpenSSL's reads of its configuration, its random numbers.
            tls_port = int(re.search(r"Modbus/TCP Security \(TLS\) on 127\.0\.0\.1:(\d+)",
                                     Path(log).read_text()).group(1))
            context = certs.context("operator")
            answer, _, session = modbus_tls(tls_port, context)
            check(answer[:1] == b"\x04", f"Modbus/TCP Security read: {answer.hex()}")
            answer, resumed, _ = modbus_tls(tls_port, context, session)
            check(answer[:1] == b"\x04" and resumed,
                  f"resumed Modbus/TCP Security read: {answer.hex()}, resumed {resumed}")
            # The HTTP side's pages read /proc/self: what the unit lets it see.
            http_port = int(re.search(r"HTTP on http://127\.0\.0\.1:(\d+)/",
                                      Path(log).read_text()).group(1))
            for page in ("/", "/metrics", "/api/v1/state", "/api/v1/trends", "/healthz", "/map"):
                with urllib.request.urlopen(f"http://127.0.0.1:{http_port}{page}", timeout=10) as r:
                    check(r.status == 200, f"GET {page}: {r.status}")

            unplug = subprocess.run([IOPORT_SIM, "ctl", f"{scratch}/hub.ctl", "unplug", "500ms"],
                                    capture_output=True, text=True)
            check(unplug.returncode == 0, f"ioport-sim ctl unplug: {unplug.stderr}")
            check(notify.wait_for(lambda m: m.startswith("STATUS=1 of 2 links up"), 10),
                  f"the unplugged link was not reported down: {notify.messages[-5:]}")
            notify.messages.clear()
            check(notify.wait_for(lambda m: m.startswith("STATUS=2 of 2 links up, 4 of 4"), 15),
                  f"the link did not come back: {notify.messages[-5:]}")
            check(notify.wait_for(lambda m: m == "WATCHDOG=1", 5), "no WATCHDOG=1")

            children = Path(f"/proc/{daemon.pid}/task/{daemon.pid}/children").read_text().split()
            check(len(children) == 1, f"strace has children {children}")
            # systemctl reload: the file is read again and a changed link restarted.
            config.write_text(config.read_text().replace("timeout: 500ms\n", "timeout: 400ms\n"))
            notify.messages.clear()
            os.kill(int(children[0]), signal.SIGHUP)
            check(notify.wait_for(lambda m: m == "READY=1", 10), "no READY=1 after SIGHUP")
            check("SIGHUP: reloaded" in Path(log).read_text(),
                  f"the reload was not applied:\n{Path(log).read_text()}")
            os.kill(int(children[0]), signal.SIGTERM)
            check(daemon.wait(timeout=10) == 0, f"ioportd exited {daemon.returncode} on SIGTERM")
            check(notify.wait_for(lambda m: m == "STOPPING=1", 1), "no STOPPING=1")

            used: dict[str, str] = {}
            socket_families: set[str] = set()
            writes: set[str] = set()
            paths: set[str] = set()
            for line in Path(trace).read_text().splitlines():
                call = re.match(r"\d+\s+([a-z0-9_]+)\((.*)", line)
                if not call:
                    continue
                name, arguments = call.groups()
                used.setdefault(name, line)
                if name == "socket":
                    socket_families.add(arguments.split(",")[0])
                looked_up = re.match(r'(?:AT_FDCWD, )?"(/[^"]*)"', arguments)
                if looked_up and name in PATH_CALLS:
                    paths.add(looked_up.group(1))
                opened = re.match(r'(?:AT_FDCWD, )?"([^"]*)", ([A-Z_|]+)', arguments)
                if name in ("open", "openat") and opened and re.search(
                        r"O_WRONLY|O_RDWR|O_CREAT|O_TRUNC", opened.group(2)):
                    writes.add(opened.group(1))
            # The first execve is strace starting ioportd: systemd applies the filter before
            # it, so it has to be allowed like any other.
            outside = sorted(set(used) - allowed)
            check(not outside, "ioportd made system calls outside the unit's SystemCallFilter="
                  " (they would fail with EPERM under systemd):\n"
                  + "\n".join(used[name] for name in outside))
            check(socket_families <= families,
                  f"ioportd opened sockets of {sorted(socket_families - families)}, outside "
                  f"RestrictAddressFamilies={' '.join(sorted(families))}")
            check(writes <= {hub, id2},
                  f"ioportd opened for writing {sorted(writes - {hub, id2})}; under "
                  f"ProtectSystem=strict only its serial ports are writable")
            hidden = sorted(p for p in paths
                            if re.match(HIDDEN_PATHS, p) and not p.startswith(scratch))
            check(not hidden, f"ioportd looked at {hidden}, which the unit hides "
                  "(ProcSubset=pid, ProtectHome=yes)")
            print(f"{len(used)} distinct system calls, socket families "
                  f"{sorted(socket_families)}, files opened for writing {sorted(writes)}")
        finally:
            if daemon and daemon.poll() is None:
                daemon.kill()
                daemon.wait()
            for sim in sims:
                sim.terminate()
                sim.wait()
    print(f"sandbox: {'failed' if failures else 'passed'}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
