"""What the Python system tests share: the real simulators on pseudo-terminals, the real daemon
on a configuration of the test's, its log, and polling with a deadline (never a fixed sleep).

    rig = Rig(directory, ioportd, ioport_sim)
    rig.start_hub("dim16:0,dom16:0")
    rig.start_id2()
    rig.write_config(yaml)        # may name rig.hub_link and rig.id2_link
    rig.start_daemon()            # waits for "ioportd ... started"
    rig.wait_log(r"...")
    rig.state(), rig.metrics()    # /api/v1/state decoded, /metrics (with http.listen set)
    rig.stop_daemon()             # SIGTERM: (seconds to the exit, exit status)
    rig.close()

Rig(..., preexec_fn=die_with_parent): the simulators and the daemon are killed when the test
process dies, even by SIGKILL (a CTest timeout); a process of the test's own can have it too.

Deadlines are upper bounds at native speed: IOPORT_TEST_SLOWDOWN in the environment (a cross
build's ctest under qemu-user, tests/CMakeLists.txt) stretches them by its factor (SLOWDOWN).
"""

import ctypes
import json
import os
import re
import signal
import socket
import subprocess
import time
import urllib.request

SLOWDOWN = int(os.environ.get("IOPORT_TEST_SLOWDOWN", "1"))


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def eventually(condition, deadline=5.0, what="condition", interval=0.01):
    """condition()'s first true result, polled every `interval` until `deadline` seconds (times
    SLOWDOWN). `what` names the condition in the failure; a callable is asked for it at the
    failure, so that it can tell what things were like then (a log, a server's answer)."""
    deadline *= SLOWDOWN
    until = time.monotonic() + deadline
    while True:
        result = condition()
        if result:
            return result
        if time.monotonic() >= until:
            raise AssertionError(f"not within {deadline} s: {what() if callable(what) else what}")
        time.sleep(interval)


def die_with_parent():
    """In the child before exec (preexec_fn): SIGKILL when the test process dies, even by
    SIGKILL (a CTest timeout), so that nothing it started outlives it."""
    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


class Rig:
    def __init__(self, directory, ioportd, ioport_sim, preexec_fn=None):
        """preexec_fn: run in each simulator and the daemon before exec (see die_with_parent)."""
        self.dir = directory
        self.ioportd = ioportd
        self.ioport_sim = ioport_sim
        self.hub_link = os.path.join(directory, "ttyHUB")
        self.id2_link = os.path.join(directory, "ttyID2")
        self.hub_ctl = os.path.join(directory, "hub.ctl")
        self.id2_ctl = os.path.join(directory, "id2.ctl")
        self.config = os.path.join(directory, "ioportd.yaml")
        self.log = os.path.join(directory, "ioportd.log")
        self.log_start = 0
        self.sims = []
        self.daemon = None
        self.preexec_fn = preexec_fn

    def start_sim(self, *args, link):
        sim = subprocess.Popen([self.ioport_sim, "--link", link, "--no-line-timing", *args],
                               stdout=subprocess.PIPE, text=True, preexec_fn=self.preexec_fn)
        self.sims.append(sim)
        banner = sim.stdout.readline()
        assert banner.startswith("ioport-sim: "), banner

    def start_hub(self, modules):
        self.start_sim("--control", self.hub_ctl, "--hub", modules, link=self.hub_link)

    def start_id2(self):
        self.start_sim("--control", self.id2_ctl, "--id2", link=self.id2_link)

    def write_config(self, yaml):
        with open(self.config, "w") as f:
            f.write(yaml)

    def start_daemon(self):
        with open(self.log, "a") as log:
            self.log_start = log.tell()
            self.daemon = subprocess.Popen([self.ioportd, "--config", self.config], stdout=log,
                                           stderr=log, preexec_fn=self.preexec_fn)
        self.wait_log(r"ioportd \S+ started: ", 10)

    def listening_port(self, what, since=0):
        """The port of the daemon's "<what> on 127.0.0.1:PORT" line, e.g. what="Modbus TCP" or
        "HTTP" (on http:// or https://)."""
        return int(self.wait_log(re.escape(what) + r" on (?:https?://)?127\.0\.0\.1:(\d+)", 5,
                                 since).group(1))

    def http_get(self, path):
        """GET `path` of the running daemon's HTTP side (its port from this start's log)."""
        port = self.listening_port("HTTP")
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as reply:
            return reply.read().decode()

    def state(self):
        """/api/v1/state, decoded."""
        return json.loads(self.http_get("/api/v1/state"))

    def metrics(self):
        """/metrics, the exposition's text."""
        return self.http_get("/metrics")

    def log_text(self):
        with open(self.log) as f:
            f.seek(self.log_start)
            return f.read()

    def log_mark(self):
        return len(self.log_text())

    def wait_log(self, pattern, timeout=5, since=0):
        def found():
            assert self.daemon.poll() is None, \
                f"ioportd exited {self.daemon.returncode}:\n{self.log_text()}"
            return re.search(pattern, self.log_text()[since:])
        return eventually(found, timeout,
                          lambda: f"/{pattern}/ in the log:\n{self.log_text()[-3000:]}")

    def reload(self, yaml):
        """Rewrites the configuration, SIGHUP, and waits for the outcome; the reload's log."""
        mark = self.log_mark()
        self.write_config(yaml)
        self.daemon.send_signal(signal.SIGHUP)
        self.wait_log(r"SIGHUP: (reloaded|.*the running configuration is kept)", 10, mark)
        return self.log_text()[mark:]

    def stop_daemon(self, sig=signal.SIGTERM, timeout=10):
        """Seconds from the signal to the exit, and the exit status; subprocess.TimeoutExpired
        if it is still running after `timeout` (times SLOWDOWN; close() kills it then)."""
        started = time.monotonic()
        self.daemon.send_signal(sig)
        code = self.daemon.wait(timeout * SLOWDOWN)
        return time.monotonic() - started, code

    def ctl(self, command, socket_path=None):
        out = subprocess.run([self.ioport_sim, "ctl", socket_path or self.hub_ctl,
                              *command.split()], capture_output=True, text=True, timeout=10)
        assert out.returncode == 0, out.stderr
        return out.stdout.splitlines()[0] if out.stdout else ""

    def close(self):
        if self.daemon and self.daemon.poll() is None:
            self.daemon.kill()
            self.daemon.wait(5)
        for sim in self.sims:
            sim.terminate()
            sim.wait(5)
            sim.stdout.close()
