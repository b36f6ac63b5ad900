#!/usr/bin/python3
"""The soak on every path (issue 42 part 3): a real mosquitto on a free loopback port, restarted
every few seconds or minutes; ioportd as a Sparkplug edge node with its store on disk, killed with
SIGKILL and started again twice (once while the broker is away, once while it is there); serial
faults re-rolled on every module every 0.5 s; Modbus writes, MQTT JSON `/set` and Sparkplug DCMD
writes taking turns on dom16 0, each checked at the simulator; and a Sparkplug host application
(host_app.py, on a persistent session) recording every value of dim16 0's `word` it receives,
live, historical (from the store) or in a birth, with its timestamp.

The soak drives the input itself: every 0.5-1 s it sets dim16 0's word to the next number of a
counter through the simulator's control socket, so every value names exactly one interval of time
in which the simulator held it. docs/faults.md ("The soak on every path") defines what counts as
lost, wrong and duplicated; in short:

  held       value v was held from the return of its `set` to the start of the next `set`
  taken      ioportd took an answer carrying v: in the simulator's transaction log, a correct
             reading of dim16 0 after which ioportd's next request came within the link's
             timeout (after any answer it did not take, a late one included, it waits a timeout
             of silence first), both from one run of ioportd
  expected   v was taken, unless it was the last value a run took before its kill -9 and no
             later run took it (it may have been on its way to the store's disk or the broker's
             socket: a kill loses nothing *written*)
  lost       an expected value that never reached the host: not live, not historical, not in a
             birth, after the final drain (broker and ioportd up, until the store is empty and
             the last value arrived)
  wrong      a value received that the simulator never answered, or stamped before its first
             answer carrying it or after ioportd's request that followed the last such answer
             (SLACK aside: the ms of the timestamps); in a birth (stamped with the birth's time),
             a value not yet answered at the birth, or older than one ioportd had surely taken
             by then (its next request had come)
  duplicated a value received in DDATA (live or historical) more than once: allowed, counted
             (docs/sparkplug.md, the store: after a lost connection a record can arrive twice;
             and after a restart the first read is stored as a change again)

Exit status 0 when nothing was lost or wrong, every write reached the simulator, the host app
saw no broken Sparkplug rule and every planned disruption happened; 1 otherwise.

Usage: soak_test.py IOPORTD IOPORT_SIM PYTHON_DIR [--duration 20] [--broker-every 7]
       [--broker-down 2] [--seed 1] [--no-store] [--no-faults]
  --no-store: ioportd without its store, to show that the soak sees the loss (it must fail).
"""
import argparse
import os
import random
import re
import shutil
import socket
import sys
import tempfile
import threading
import time

parser = argparse.ArgumentParser()
parser.add_argument("ioportd")
parser.add_argument("ioport_sim")
parser.add_argument("python_dir")
parser.add_argument("--duration", type=float, default=20.0, help="seconds of disruption")
parser.add_argument("--broker-every", type=float, default=7.0,
                    help="seconds between broker restarts")
parser.add_argument("--broker-down", type=float, default=2.0,
                    help="seconds the broker stays away")
parser.add_argument("--seed", type=int, default=1)
parser.add_argument("--no-store", action="store_true")
parser.add_argument("--no-faults", action="store_true")
ARGS = parser.parse_args()

sys.path.insert(0, ARGS.python_dir)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))

import paho.mqtt.client as mqtt  # noqa: E402
from pymodbus.client import ModbusTcpClient  # noqa: E402

from broker import Broker  # noqa: E402
from host_app import HostApp  # noqa: E402
from rig import Rig, die_with_parent, eventually  # noqa: E402

GROUP, NODE = "plant1", "box7"
JSON_PREFIX = "ioportd/box7"
INPUT, OUTPUT = "hub0.dim16.0", "hub0.dom16.0"
TIMEOUT = 0.1  # s: the link's `timeout` (the configuration below)
READ_INPUT = "a0"  # dim16 0's request; its answer is the word in 4 hex digits
# s: the daemon's millisecond timestamps, and this process's two clocks read one after the other
SLACK = 0.005
FAULT_KINDS = ["silent", "error-ack", "garbage", "short", "long", "delay"]


class RecordingHost(HostApp):
    """The host app of the Sparkplug tests, also keeping every value of every device metric it
    receives: (kind, device, name, value, timestamp ms), kind live, historical or birth."""

    def __init__(self, *args, **kwargs):
        self.records = []
        super().__init__(*args, **kwargs)

    def _data(self, device_state, message):
        super()._data(device_state, message)
        for m in message.metrics:
            if m.alias is not None and m.alias in device_state.by_alias:
                name = device_state.by_alias[m.alias][0]
            else:
                name = m.name
            self.records.append(("historical" if m.is_historical else "live", message.device,
                                 name, m.value, m.timestamp))

    def _dbirth(self, state, message):
        super()._dbirth(state, message)
        for m in message.metrics:
            self.records.append(("birth", message.device, m.name, m.value, m.timestamp))


class SimControl:
    """The simulator's control socket: a line out, lines back until `ok …` or `error …`."""

    def __init__(self, path):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.settimeout(5)
        self.sock.connect(path)
        self.pending = b""
        self.lock = threading.Lock()

    def command(self, line):
        with self.lock:
            self.sock.sendall(line.encode() + b"\n")
            lines = []
            while True:
                while b"\n" not in self.pending:
                    data = self.sock.recv(4096)
                    if not data:
                        raise RuntimeError(f"the simulator closed its control socket on {line}")
                    self.pending += data
                reply, self.pending = self.pending.split(b"\n", 1)
                reply = reply.decode()
                if reply == "ok" or reply.startswith("ok "):
                    lines.append(reply[3:])
                    return "\n".join(x for x in lines if x)
                if reply.startswith("error"):
                    raise RuntimeError(f"simulator: {line}: {reply}")
                lines.append(reply)


class Soak:
    def __init__(self):
        self.random = random.Random(ARGS.seed)
        self.setter_random = random.Random(ARGS.seed + 1)  # the setter thread's own
        self.dir = tempfile.mkdtemp(prefix="ioportd-spb-soak-")
        self.broker = Broker(self.dir, keep_sessions=True)
        self.broker.start()
        self.host = RecordingHost(self.broker.port, client_id="ioportd-soak-host",
                                  keep_session=True)
        self.json = mqtt.Client(client_id="ioportd-soak-json", protocol=mqtt.MQTTv311)
        self.json.reconnect_delay_set(0.05, 0.2)
        self.json.connect_async("127.0.0.1", self.broker.port, keepalive=10)
        self.json.loop_start()
        self.rig = Rig(self.dir, ARGS.ioportd, ARGS.ioport_sim, preexec_fn=die_with_parent)
        self.rig.start_hub("dim16:0,dom16:0")
        self.sim = SimControl(self.rig.hub_ctl)
        # The simulator's transaction log, on this process's clock: its times are µs since its
        # start on CLOCK_MONOTONIC, which time.monotonic() reads too.
        self.sim_started = int(self.sim.command("clock").split()[0]) / 1e6
        self.sim.command("log clear")
        self.transactions = []  # (time, request, answer), answer "-" when silent
        store = os.path.join(self.dir, "store")
        os.mkdir(store, 0o700)
        store_line = "" if ARGS.no_store else f"  store: {{ path: {store}, forward_rate: 50 }}\n"
        self.rig.write_config(f"""modbus:
  listen: "127.0.0.1:0"
http:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {self.rig.hub_link}
    unit_id: 1
    timeout: {TIMEOUT * 1000:.0f}ms
    retries: 3
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0, refresh: 1s }}
mqtt:
  broker: "mqtt://127.0.0.1:{self.broker.port}"
  group_id: {GROUP}
  edge_node_id: {NODE}
  keepalive: 5s
{store_line}mqtt_json:
  broker: "mqtt://127.0.0.1:{self.broker.port}"
  topic_prefix: "{JSON_PREFIX}"
  keepalive: 5s
""")
        # What the simulator held: (value, set called, set returned); value 0 from the start.
        self.sets = [(0, 0.0, 0.0)]
        self.counter = 0
        self.up = []  # [start, end) of each run of ioportd, end None while it runs
        self.kills = 0
        self.kill_windows = []  # (the kill, the next start) of each kill -9
        self.broker_restarts = 0
        self.fault_rolls = 0
        self.writes = {"modbus": 0, "json": 0, "dcmd": 0}
        self.writes_not_applied = []
        self.writes_refused = 0
        self.timeline = []  # (time, event)
        self.t0 = time.time()
        self.modbus = None
        self.stop_setting = threading.Event()

    # --- ioportd -------------------------------------------------------------------------------

    def start_daemon(self):
        self.rig.start_daemon()
        self.up.append([time.time(), None])
        self.modbus_port = self.rig.listening_port("Modbus TCP")
        self.modbus = ModbusTcpClient("127.0.0.1", port=self.modbus_port, timeout=3)
        self.marks()

    def kill_daemon(self):
        self.kill_windows.append([time.time(), None])
        if self.modbus:
            self.modbus.close()
            self.modbus = None
        self.up[-1][1] = time.time()
        self.rig.stop_daemon(9)
        self.kills += 1

    def marks(self):
        self.json_mark = 0  # where to look for mqtt_json's connection in this start's log
        self.host_mark = len(self.host.messages)

    # --- the input, set by a thread of its own ------------------------------------------------

    def setter(self):
        while not self.stop_setting.is_set():
            self.counter += 1
            value = self.counter % 65536
            called = time.time()
            self.sim.command(f"set dim16:0 {value}")
            self.sets.append((value, called, time.time()))
            self.stop_setting.wait(self.setter_random.uniform(0.5, 1.0))

    # --- the writes ----------------------------------------------------------------------------

    def write_ready(self, path, broker_up):
        if path == "modbus":
            return True
        if not broker_up:
            return False
        if path == "dcmd":
            # The node subscribes to its commands before its NBIRTH.
            return any(m.type == "NBIRTH" and m.node == NODE
                       for m in self.host.messages[self.host_mark:])
        # mqtt_json subscribes to its sets as soon as it has logged its connection.
        return "mqtt_json: connected to" in self.rig.log_text()[self.json_mark:]

    def write(self, path, value):
        if path == "modbus":
            try:
                if not self.modbus.connected:
                    self.modbus.connect()
                reply = self.modbus.write_register(0, value, slave=1)
            except Exception:  # pymodbus raises on a connection it lost: never acknowledged
                return False
            if reply.isError():
                return False  # refused, never acknowledged: nothing to check
        elif path == "json":
            self.json.publish(f"{JSON_PREFIX}/hub0/dom16_0/word/set", str(value), qos=1)
        else:
            self.host.dcmd(GROUP, NODE, OUTPUT, [{"name": "word", "value": value,
                                                  "datatype": "UInt16"}])
        self.writes[path] += 1
        # A write the device refused (a fault answered it with an exception, or it never
        # answered through every retry) is logged as such and reaches nothing: counted, not
        # lost. Anything else must show at the simulator.
        pattern = re.compile(rf"write by {'mqtt_json' if path == 'json' else 'sparkplug'} .*"
                             rf"= {value}: (?!confirmed)(\S+)")

        def outcome():
            if int(self.sim.command("get dom16:0"), 0) == value:
                return "applied"
            if path != "modbus" and pattern.search(self.rig.log_text()):
                return "refused"
            return None
        try:
            if eventually(outcome, 5) == "refused":
                self.writes_refused += 1
        except AssertionError:
            self.writes_not_applied.append((path, value, time.time() - self.t0))
        return True

    # --- the run -------------------------------------------------------------------------------

    def roll_faults(self):
        for module in ("dim16:0", "dom16:0"):
            kind = self.random.choice(FAULT_KINDS)
            probability = self.random.uniform(0.01, 0.10)
            self.sim.command(f"fault {module} {kind} {probability:.3f}"
                             + (" 150ms" if kind == "delay" else ""))
        self.fault_rolls += 1

    def run(self):
        self.start_daemon()
        setter = threading.Thread(target=self.setter, daemon=True)
        setter.start()
        began = time.monotonic()
        end = began + ARGS.duration
        events = []
        at = ARGS.broker_every
        while at + ARGS.broker_down < ARGS.duration:
            events += [(at, "broker stop"), (at + ARGS.broker_down, "broker start")]
            at += ARGS.broker_every
        first = ARGS.broker_every
        # One SIGKILL while the broker is away (the store on disk carries what changed), one
        # while it is there.
        events += [(first + ARGS.broker_down / 2, "kill"),
                   (first + ARGS.broker_every / 2, "kill")]
        events.sort()
        planned = {"broker stop": sum(1 for _, e in events if e == "broker stop"),
                   "kill": sum(1 for _, e in events if e == "kill")}
        broker_up = True
        next_faults = began
        turn = 0
        paths = ["modbus", "json", "dcmd"]
        while time.monotonic() < end:
            now = time.monotonic() - began
            while events and events[0][0] <= now:
                _, event = events.pop(0)
                self.timeline.append((time.time() - self.t0, event))
                if event == "broker stop":
                    self.broker.stop()
                    broker_up = False
                elif event == "broker start":
                    self.broker.start()
                    self.broker_restarts += 1
                    broker_up = True
                    self.host_mark = len(self.host.messages)
                    self.json_mark = len(self.rig.log_text())
                else:
                    self.kill_daemon()
                    self.start_daemon()
                    self.kill_windows[-1][1] = time.time()
            self.take_log()
            if not ARGS.no_faults and time.monotonic() >= next_faults:
                self.roll_faults()
                next_faults = time.monotonic() + 0.5
            path = paths[turn % 3]
            turn += 1
            if self.write_ready(path, broker_up):
                self.write(path, self.random.randrange(1, 65536))
            # Writes go before polls on the bus: a pause leaves the polls their share, as a
            # SCADA writing a few times a second would.
            time.sleep(0.1)
        self.stop_setting.set()
        setter.join(10)
        self.sim.command("fault all none")
        self.setting_ended = time.time()
        faults = self.injected()
        self.drain()
        self.up[-1][1] = self.setting_ended
        return planned, faults

    def injected(self):
        words = self.sim.command("faults").split()
        return sum(int(n) for n in words[1::2] if n.isdigit())

    def drain(self):
        """Broker and ioportd up: wait until the store is empty and the last value arrived."""
        last = self.sets[-1][0]

        def drained():
            if not any(r[0] != "birth" and r[1] == INPUT and r[2] == "word" and r[3] == last
                       for r in self.host.records):
                return False
            if ARGS.no_store:
                return True
            return self.rig.state()["sparkplug"]["store"]["records"] == 0
        try:
            eventually(drained, 60, "the store drained and the last value arrived", 0.1)
        except AssertionError as e:
            print(f"soak: {e}", file=sys.stderr)
        self.take_log()

    def take_log(self):
        """Moves the simulator's transaction log here (it keeps the last 100,000 transactions:
        taken at every turn of the run, it never fills)."""
        lines = self.sim.command("log take").split("\n")
        count = int(lines.pop())
        entries = [line.split(" ", 2) for line in lines]
        assert len(entries) == count and all(len(e) == 3 for e in entries), lines[:5]
        # On the wall clock as it is now: a slewed clock moves little within one take.
        epoch = self.sim_started + time.time() - time.monotonic()
        self.transactions += [(epoch + int(at) / 1e6, request, answer)
                              for at, request, answer in entries]

    def taken(self):
        """(time, time of the next request, value) of every answer to dim16 0 that ioportd took, from the simulator's
        log: a correct reading, after which ioportd's next request came within TIMEOUT of this
        one. That is the one way to go on so soon: after a reading it did not take (no answer
        within the timeout, a wrong one, an answer followed by another) the link first waits for
        a timeout of silence on the line, and after a first reading that follows a failure it
        waits a timeout for any answer still owed (link/serial_link.cpp). So a late answer (a
        delay fault, or a machine too slow to read it in time) never counts, nor does a pair of
        transactions across a kill -9 and the restart after it (two processes)."""
        readings = []
        log = self.transactions
        for (t, request, answer), (t_next, _, _) in zip(log, log[1:]):
            if request != READ_INPUT or not re.fullmatch(r"[0-9A-F]{4}", answer) or \
                    t_next - t >= TIMEOUT:
                continue
            if any(t <= restarted and killed <= t_next for killed, restarted in self.kill_windows):
                continue
            readings.append((t, t_next, int(answer, 16)))
        return readings

    def answered(self):
        """value -> [when the simulator first answered it, when ioportd's request after its last
        answer carrying it came]: every correct reading of dim16 0, taken or not. ioportd can
        stamp a value only between the two (its next request follows whatever it made of an
        answer)."""
        spans = {}
        log = self.transactions
        for i, (t, request, answer) in enumerate(log):
            if request != READ_INPUT or not re.fullmatch(r"[0-9A-F]{4}", answer):
                continue
            after = log[i + 1][0] if i + 1 < len(log) else float("inf")
            spans.setdefault(int(answer, 16), [t, after])[1] = after
        return spans

    # --- the verdict ---------------------------------------------------------------------------

    def analyse(self):
        sets = self.sets
        received = {}  # value -> [(kind, timestamp s)]
        wrong = []
        order = {value: index for index, (value, _, _) in enumerate(sets)}
        answered = self.answered()
        readings = self.taken()
        for kind, device, name, value, stamp in list(self.host.records):
            if device != INPUT or name != "word":
                continue
            t = stamp / 1000.0
            received.setdefault(value, []).append((kind, t))
            span = answered.get(value)
            if span is None:  # never on the line
                wrong.append((kind, value, t))
            elif kind == "birth":
                # The last value read, stamped with the birth's own time: on the line before the
                # birth, and no older than any value ioportd had surely taken by then.
                known = [v for _, t_next, v in readings if t_next <= t - SLACK]
                if span[0] > t + SLACK or (known and order[value] < order[known[-1]]):
                    wrong.append((kind, value, t))
            elif not span[0] - SLACK <= t <= span[1] + SLACK:
                wrong.append((kind, value, t))
        taken = {}  # value -> times ioportd took an answer carrying it
        for t, _, value in readings:
            taken.setdefault(value, []).append(t)
        # The last value a run killed with SIGKILL took may have been on its way to the store's
        # disk thread or to the broker's socket (a kill loses nothing *written*,
        # docs/sparkplug.md): it is expected only if a later run took it too.
        last_before_kill = set()
        for killed, _ in self.kill_windows:
            before = [value for t, _, value in readings if t < killed]
            if before and max(taken[before[-1]]) < killed:
                last_before_kill.add(before[-1])
        expected = [v for v, _, _ in sets[1:] if v in taken and v not in last_before_kill]
        not_taken = [v for v, _, _ in sets[1:] if v not in taken]
        lost = [v for v in expected if v not in received]
        duplicated = sum(max(0, sum(1 for k, _ in r if k != "birth") - 1)
                         for r in received.values())
        kinds = {"live": 0, "historical": 0, "birth": 0}
        for r in received.values():
            for k, _ in r:
                kinds[k] += 1
        return (expected, not_taken, last_before_kill, lost, wrong, duplicated, kinds, received,
                taken)

    def close(self):
        self.stop_setting.set()
        self.json.loop_stop()
        self.host.close()
        self.rig.close()
        self.broker.stop()


def main():
    soak = Soak()
    started = time.monotonic()
    try:
        planned, faults = soak.run()
        (expected, not_taken, last_before_kill, lost, wrong, duplicated, kinds, received,
         taken) = soak.analyse()
    finally:
        elapsed = time.monotonic() - started
        soak.close()
    changes = len(soak.sets) - 1
    violations = soak.host.violations
    store = ", NO STORE" if ARGS.no_store else ""
    lines = [
        f"ioportd soak on every path: {elapsed:.0f} s ({ARGS.duration:.0f} s of disruption), "
        f"seed {ARGS.seed}{store}",
        f"  input changes          {changes} (dim16 0 word, a counter, every 0.5-1 s)",
        f"  expected at the host   {len(expected)} (ioportd took an answer carrying it: "
        f"{sum(len(t) for t in taken.values())} readings of {len(soak.transactions)} "
        "transactions)",
        f"  never taken            {len(not_taken)} (never in an answer ioportd took: dim16 0 "
        "failing, the daemon down, or too short)",
        f"  cut by a kill -9       {len(last_before_kill)} (the last value a killed run took, "
        "taken by no later run" + "".join(
            f"; {v} at {max(taken[v]) - soak.t0:.3f} s, "
            f"{'received' if v in received else 'not received'}" for v in last_before_kill)
        + ")",
        f"  received               {kinds['live']} live, {kinds['historical']} historical, "
        f"{kinds['birth']} in births ({len(received)} distinct values)",
        f"  broker restarts        {soak.broker_restarts} (down {ARGS.broker_down:.0f} s each)",
        f"  kill -9                {soak.kills} (and restarted, the store on disk)",
        f"  serial faults          {faults} injected ({soak.fault_rolls} re-rolls of 1-10 % on "
        "each module)",
        f"  writes                 {soak.writes['modbus']} Modbus, {soak.writes['json']} MQTT "
        f"JSON /set, {soak.writes['dcmd']} DCMD; not at the simulator: "
        f"{len(soak.writes_not_applied)} (refused by the device, a fault: {soak.writes_refused})",
        f"  values lost            {len(lost)}",
        f"  values wrong           {len(wrong)}",
        f"  values duplicated      {duplicated}",
        f"  Sparkplug violations   {len(violations)}",
    ]
    print("\n".join(lines))
    for v in lost[:20]:
        called, returned, nxt = next((c, r, n) for (x, c, r), (_, n, _) in
                                     zip(soak.sets, soak.sets[1:] + [(0, soak.setting_ended, 0)])
                                     if x == v)
        print(f"  lost: {v}, held {returned - soak.t0:.3f}-{nxt - soak.t0:.3f} s, taken at "
              + ", ".join(f"{t - soak.t0:.3f}" for t in taken[v][:5])
              + (f" and {len(taken[v]) - 5} more" if len(taken[v]) > 5 else ""))
    if lost or wrong:
        print("  runs of ioportd: " + ", ".join(
            f"{a - soak.t0:.3f}-{b - soak.t0:.3f}" for a, b in soak.up))
        print("  events: " + ", ".join(f"{t:.3f} {e}" for t, e in soak.timeline))
    for kind, value, t in wrong[:20]:
        print(f"  wrong: {value} ({kind}) stamped {t - soak.t0:.3f} s")
    for w in soak.writes_not_applied[:20]:
        print(f"  write not applied: {w}")
    for v in violations[:20]:
        print(f"  violation: {v}")
    print(f"SOAK_SPB seconds={elapsed:.0f} changes={changes} expected={len(expected)} "
          f"broker_restarts={soak.broker_restarts} kills={soak.kills} faults={faults} "
          f"writes={sum(soak.writes.values())} writes_not_applied={len(soak.writes_not_applied)} "
          f"lost={len(lost)} wrong={len(wrong)} duplicated={duplicated} "
          f"violations={len(violations)}")
    ok = (not lost and not wrong and not soak.writes_not_applied and not violations
          and soak.kills == planned["kill"] and soak.broker_restarts == planned["broker stop"]
          and min(soak.writes.values()) > 0 and len(expected) > 0)
    if ok:
        shutil.rmtree(soak.dir, ignore_errors=True)
    else:
        with open(os.path.join(soak.dir, "received.txt"), "w") as f:
            for value, called, returned in soak.sets:
                f.write(f"set {value} {called - soak.t0:.3f} {returned - soak.t0:.3f}\n")
            for kind, device, name, value, stamp in soak.host.records:
                if device == INPUT and name == "word":
                    f.write(f"{kind} {value} {stamp / 1000 - soak.t0:.3f}\n")
        with open(os.path.join(soak.dir, "transactions.txt"), "w") as f:
            for t, request, answer in soak.transactions:
                f.write(f"{t - soak.t0:.6f} {request} {answer}\n")
        print(f"soak: logs kept in {soak.dir}", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
