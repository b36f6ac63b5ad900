#!/usr/bin/python3
"""The fleet on a real broker cluster (issue 49): two-node clusters of ejabberd 23.01 (mod_mqtt)
and RabbitMQ 3.10 (rabbitmq_mqtt) from Debian, started by the test on loopback
(tests/support/cluster.py: their own node names, cookie, epmd and ports), the real simulator on
a pty and the real daemon with `brokers: [node 1, node 2]` on both of its MQTT outputs, the
Sparkplug edge node (`mqtt:`, with a store) and plain MQTT (`mqtt_json:`).

On node 2, which stays up throughout, a Sparkplug host application (host_app.py, which checks the
specification's rules on every message) and a Home Assistant-like subscriber. Node 1 is stopped
cleanly, or killed (SIGKILL of its Erlang VM), while dim16 0's inputs change CHANGES times at the
simulator (and on until the daemon's new session began), each change waited for in the daemon's
Modbus image: every change must reach the host on node 2 once, live or as history forwarded from
the store (none twice; none lost but, at most, the live DDATA in flight when node 1 closed the
connection, which Sparkplug's QoS 0 leaves unproven), and no will of the dead node's sessions reaches it; the JSON
state on node 2 must be current, and the gateway's status online after a Home Assistant birth on
node 2. Each run prints its failover figures (seconds from the stop or kill to the daemon's new
session on node 2, per output; values live, historical, lost, duplicated), and the module ends
with the table of them all.

RabbitMQ besides: MQTT 5 is closed without a CONNACK there, so both outputs must fall back to
3.1.1 and connect; `mqtt.sparkplug = true` and `device_id_separator: _` (docs/sparkplug.md) make
a DCMD act, and one whose device id the broker cut into levels, or that names no device, is
counted in ioportd_sparkplug_commands_total{result="unknown_device"}. A kill of node 1 is
survived only with the mirrored-queue policy on the MQTT plugin's queues.

Mosquitto 2.0 besides (MosquittoBridge): two brokers, node 1 bridged to node 2 by a `connection`
carrying spBv1.0/#, ioportd/# and homeassistant/# both ways, the same failovers; retained messages
cross the bridge, and a clean stop of node 1 publishes the wills of its sessions, which cross it
before it closes. The bounds on a message's size: ejabberd's max_payload_size (EjabberdSizes, on
one-node ejabberds of their own: by default ejabberd sends the daemon a DCMD over its MQTT 5
Maximum Packet Size; 65536 keeps it away; a limit under a DBIRTH ends every session the daemon
begins, with its will) and RabbitMQ's max_message_size (likewise, set on the running nodes).

A cluster that cannot start here is a failure, with the reason (ClusterError): nothing is skipped.
Deadlines are upper bounds at native speed, stretched by IOPORT_TEST_SLOWDOWN.

Usage: fleet_test.py IOPORTD IOPORT_SIM PYTHON_DIR [tests]  (PYTHON_DIR holds sparkplug_b_pb2.py)
"""
import json
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
import unittest

IOPORTD, IOPORT_SIM, PYTHON_DIR = sys.argv[1], sys.argv[2], sys.argv[3]
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, PYTHON_DIR)
sys.path.insert(0, os.path.join(HERE, "..", "sparkplug"))
sys.path.insert(0, os.path.join(HERE, "..", "support"))

import paho.mqtt.client as mqtt  # noqa: E402
from pymodbus.client import ModbusTcpClient  # noqa: E402

import sparkplug_b_pb2 as pb  # noqa: E402
from broker import BridgedMosquitto  # noqa: E402
from cluster import EjabberdCluster, RabbitCluster  # noqa: E402
from host_app import HostApp, encode_value  # noqa: E402
from rig import SLOWDOWN, Rig, die_with_parent, eventually  # noqa: E402

GROUP, NODE = "plant1", "box7"
PREFIX = "ioportd/box7"
HA = "homeassistant"
CHANGES = 150
BARRIER = 0xF000  # a value none of the changes takes: once it is live, all before it arrived
STATUS = f"{PREFIX}/status"
DIM_STATE = f"{PREFIX}/hub0/dim16_0/state"
# Exact topics, no wildcards: RabbitMQ 3.10 sends a retained message only to a subscription
# whose filter is its very topic.
HA_TOPICS = (STATUS, DIM_STATE, f"{PREFIX}/hub0/dim16_0/availability",
             f"{PREFIX}/hub0/dom16_0/state")

FIGURES = []  # one row per failover run, printed at the end
WILLS = []  # per clean stop of a bridged Mosquitto: (the NDEATH crossed, the JSON will crossed)
DEFAULT_MAX_MESSAGE_SIZE = 134217728  # RabbitMQ 3.10's max_message_size: 128 MiB


class FleetRig(Rig):
    """ioport-sim with dim16 0 and dom16 0, and ioportd on it with both MQTT outputs on the
    cluster's nodes in order, the Sparkplug store in the rig's directory."""

    def __init__(self, directory, cluster, separator=".", primary_host=None):
        super().__init__(directory, IOPORTD, IOPORT_SIM, preexec_fn=die_with_parent)
        self.urls = [f"mqtt://127.0.0.1:{node.mqtt_port}" for node in cluster.nodes]
        self.store = os.path.join(directory, "store")
        login = ""
        if cluster.credentials:
            user, password = cluster.credentials
            path = os.path.join(directory, "password")
            with open(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), "w") as f:
                f.write(password + "\n")
            login = f"  username: {user}\n  password_file: {path}\n"
        try:
            self.start_hub("dim16:0,dom16:0")
        except BaseException:
            self.close()
            raise
        brokers = json.dumps(self.urls)
        self.write_config(f"""modbus:
  listen: "127.0.0.1:0"
http:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {self.hub_link}
    unit_id: 1
    timeout: 100ms
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0 }}
mqtt:
  brokers: {brokers}
  group_id: {GROUP}
  edge_node_id: {NODE}
  keepalive: 5s
  device_id_separator: "{separator}"
  store: {{ path: {self.store} }}
{f"  primary_host_id: {primary_host}{chr(10)}" if primary_host else ""}{login}mqtt_json:
  brokers: {brokers}
  topic_prefix: "{PREFIX}"
  keepalive: 5s
{login}""")

    def start_daemon(self):
        super().start_daemon()
        self.modbus_port = self.listening_port("Modbus TCP")

    def wait_connected(self, section, url, since=0, timeout=30):
        """The log's `<section>: connected to <url> as ... (MQTT <version>)`: the version."""
        return self.wait_log(rf"(?m)^.*{section}: connected to {re.escape(url)} as \S+ "
                             r"\(MQTT ([0-9.]+)\)", timeout, since).group(1)


class Watcher:
    """A Home Assistant-like MQTT 3.1.1 client on one node: every message of `topics` with its
    retain flag and arrival time; publishes at QoS 1."""

    def __init__(self, cluster, index, topics=HA_TOPICS, client_id=None):
        self.messages = []  # (topic, payload, retain, monotonic)
        self.lock = threading.Lock()
        self.client = mqtt.Client(client_id or f"ha-like-{time.monotonic_ns()}",
                                  clean_session=True, protocol=mqtt.MQTTv311)
        if cluster.credentials:
            self.client.username_pw_set(*cluster.credentials)
        self.client.on_message = self._message
        connected, subscribed = threading.Event(), threading.Event()
        self.client.on_connect = lambda _c, _u, _f, rc: rc == 0 and connected.set()
        self.client.on_subscribe = lambda *_: subscribed.set()
        self.client.connect("127.0.0.1", cluster.nodes[index].mqtt_port, keepalive=30)
        self.client.loop_start()
        eventually(connected.is_set, 10, f"CONNACK from node {index + 1}")
        if topics:
            self.client.subscribe([(t, 1) for t in topics])
            eventually(subscribed.is_set, 10, f"SUBACK from node {index + 1}")

    def _message(self, _client, _userdata, m):
        with self.lock:
            self.messages.append((m.topic, m.payload.decode("utf-8", "replace"), bool(m.retain),
                                  time.monotonic()))

    def mark(self):
        with self.lock:
            return len(self.messages)

    def since(self, mark=0, topic=None):
        with self.lock:
            return [m for m in self.messages[mark:] if topic is None or m[0] == topic]

    def wait(self, topic, where=lambda m: True, since=0, timeout=60):
        def found():
            return next((m for m in self.since(since, topic) if where(m)), None)
        return eventually(found, timeout, lambda: f"{topic} since #{since}; got "
                          f"{[(m[0], m[1][:60], m[2]) for m in self.since(since)][-10:]}")

    def publish(self, topic, payload, retain=False):
        self.client.publish(topic, payload, qos=1, retain=retain).wait_for_publish(10)

    def close(self):
        self.client.disconnect()
        self.client.loop_stop()


def retained(cluster, index, topics):
    """What node `index` keeps retained under these exact topics, for a new subscriber: each
    topic's payload. A message the subscriber publishes after its SUBACK to a topic of its own
    arrives after the retained ones (the node queued them when it took the SUBSCRIBE)."""
    barrier = f"test/barrier/{time.monotonic_ns()}"
    watcher = Watcher(cluster, index, (*topics, barrier))
    try:
        watcher.publish(barrier, "end")
        watcher.wait(barrier)
        return {topic: payload for topic, payload, kept, _ in watcher.since()
                if kept and topic != barrier}
    finally:
        watcher.close()


def command_payload(metrics):
    payload = pb.Payload(timestamp=int(time.time() * 1000))
    for name, datatype, value in metrics:
        encode_value(payload.metrics.add(name=name), datatype, value)
    return payload.SerializeToString()


class FleetCase(unittest.TestCase):
    """One cluster for the class, a Sparkplug host application on node 2 throughout."""
    SEPARATOR = "."
    WILL_AT_STOP = False  # the wills of node 1's sessions reach node 2 when it stops cleanly

    @classmethod
    def make_cluster(cls, directory):
        raise NotImplementedError

    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="ioportd-fleet-")
        cls.cluster = cls.make_cluster(os.path.join(cls.dir, "cluster"))
        began = time.monotonic()
        cls.cluster.start()  # ClusterError with the reason: a failure, never a skip
        print(f"\n  {cls.cluster.kind}: two nodes up and clustered in "
              f"{time.monotonic() - began:.1f} s", file=sys.stderr)
        cls.host = HostApp(cls.cluster.nodes[1].mqtt_port, client_id="fleet-host-on-node2",
                           credentials=cls.cluster.credentials)

    @classmethod
    def tearDownClass(cls):
        cls.host.close()
        cls.cluster.close()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def setUp(self):
        self.rig = None
        self.host_violations_allowed = []
        if not self.cluster.nodes[0].running():
            seconds = self.cluster.start_node(0)
            print(f"\n  {self.cluster.kind}: node 1 back in the cluster in {seconds:.1f} s",
                  file=sys.stderr)

    def tearDown(self):
        if self.rig:
            daemon = self.rig.daemon
            if daemon and daemon.poll() is None:
                mark = self.host.mark()
                self.rig.stop_daemon(signal.SIGTERM)
                state = self.host.node(GROUP, NODE)
                if state and state.born:
                    self.host.wait_message("NDEATH", node=NODE, since=mark, timeout=60)
            self.rig.close()
        violations = [v for v in self.host.violations
                      if not any(re.search(allowed, v) for allowed in self.host_violations_allowed)]
        self.host.violations[:] = []
        self.assertEqual(violations, [], "Sparkplug rules broken at the host on node 2")

    def url(self, index):
        return f"mqtt://127.0.0.1:{self.cluster.nodes[index].mqtt_port}"

    def device(self, kind):
        return self.SEPARATOR.join(("hub0", kind, "0"))

    def start_rig(self):
        """A new daemon, connected to node 1 on both outputs and born at the host on node 2:
        the NBIRTH message."""
        self.rig = FleetRig(tempfile.mkdtemp(dir=self.dir), self.cluster, self.SEPARATOR)
        # what an earlier daemon left retained, on each node (they keep their own)
        for index in range(len(self.cluster.nodes)):
            watcher = Watcher(self.cluster, index, ())
            try:
                for topic in HA_TOPICS:
                    watcher.publish(topic, "", retain=True)
            finally:
                watcher.close()
        mark = self.host.mark()
        self.rig.start_daemon()
        for section in ("mqtt", "mqtt_json"):
            self.rig.wait_connected(section, self.url(0))
        nbirth = self.host.wait_message("NBIRTH", node=NODE, since=mark, timeout=60)
        for kind in ("dim16", "dom16"):
            self.host.wait_message("DBIRTH", self.device(kind), since=nbirth.index, timeout=60)
        return nbirth

    def modbus_word(self, client):
        reply = client.read_input_registers(0, 1, slave=1)  # dim16 0, its 16 inputs as a word
        return None if reply.isError() else reply.registers[0]

    def set_word(self, client, value):
        """dim16 0 set to `value` at the simulator, and waited for in the daemon's image."""
        self.rig.ctl(f"set dim16:0 0x{value:04x}")
        eventually(lambda: self.modbus_word(client) == value, 10,
                   lambda: f"dim16 0 = 0x{value:04x} in the Modbus image "
                           f"(0x{self.modbus_word(client) or 0:04x})")

    def failover(self, mode, label=None, blocked_for=0):
        """Node 1 stopped (`mode` "stop") or killed ("kill") while dim16 0 changes CHANGES times;
        checks that every change reaches the host on node 2 once and that the JSON side is
        current there; records the figures in FIGURES under `label` (default: `mode`).

        blocked_for: the failover is expected not to happen: for that many seconds no session
        of the daemon reaches the host, and node 2 closes every connection the daemon makes;
        then node 1 is started again, and the session may be on either node."""
        cluster, host = self.cluster, self.host
        born = self.start_rig().metric("bdSeq").value
        ha = Watcher(cluster, 1)
        client = ModbusTcpClient("127.0.0.1", port=self.rig.modbus_port, timeout=3)
        self.assertTrue(client.connect())
        stopped = []
        try:
            mark, ha_mark, log = host.mark(), ha.mark(), self.rig.log_mark()
            began = time.monotonic()
            if mode == "stop":
                # the stop command returns when the node's VM has exited, seconds later: the
                # changes go on meanwhile
                stopper = threading.Thread(target=lambda: stopped.append(cluster.stop_node(0)))
                stopper.start()
            else:
                stopped.append(cluster.kill_node(0))
            # CHANGES at least, and on until the new session began, so that they span it (a
            # node stopping cleanly may take longer than the changes do)
            total = 0
            while total < CHANGES or not (blocked_for or host.since(mark, "NBIRTH", node=NODE)):
                total += 1
                self.set_word(client, total)
                self.assertLess(total, BARRIER, "no new session while the input changed")
            changed = time.monotonic() - began
            if mode == "stop":
                stopper.join(90 * SLOWDOWN)
                self.assertFalse(stopper.is_alive(), "node 1's stop did not end")
            # the old session ended where the host could not see it (checked below): the new
            # NBIRTH comes without an NDEATH before it
            self.host_violations_allowed.append(
                r"^\[nbirth\] .*NBIRTH bdSeq \d+ while the session of bdSeq \d+ had no NDEATH$")
            closed = 0
            if blocked_for:
                until = began + blocked_for
                while time.monotonic() < until:
                    self.assertEqual(host.since(mark, "NBIRTH", node=NODE), [],
                                     "a session of the daemon reached the host")
                    time.sleep(0.1)
                closed = len(re.findall(
                    rf"(?m)^.* mqtt: {re.escape(self.url(1))} closed the connection",
                    self.rig.log_text()[log:]))
                self.assertGreaterEqual(closed, 2, self.rig.log_text()[log:][-3000:])
                restarted = cluster.start_node(0)
                print(f"\n  {cluster.kind}: no session for {blocked_for} s, node 2 closed the "
                      f"connection {closed} times; node 1 back in the cluster in "
                      f"{restarted:.1f} s", file=sys.stderr)
            # the new sessions (on node 2)
            nbirth = host.wait_message("NBIRTH", node=NODE, since=mark, timeout=60)
            spb_seconds = nbirth.received - began
            # live, not a retained copy (through a bridge, node 2 has node 1's: the watcher's
            # subscription may get it just after the mark)
            online = ha.wait(STATUS, lambda m: m[1] == "online" and not m[2] and m[3] > began,
                             ha_mark, timeout=60)
            json_seconds = online[3] - began
            json_offline = [m[1] for m in ha.since(ha_mark, STATUS)
                            if m[1] == "offline" and m[3] < online[3]]
            if not blocked_for:
                for section in ("mqtt", "mqtt_json"):
                    self.assertEqual(self.rig.wait_connected(section, self.url(1), log),
                                     "3.1.1" if isinstance(cluster, RabbitCluster) else "5")
                self.assertEqual(self.rig.state()["sparkplug"]["broker"], self.url(1))
            # every change, live or forwarded; the store emptied; then a barrier
            device = self.device("dim16")

            def values():
                live, history, births = [], [], []
                for m in host.since(mark, device=device):
                    if m.type == "DDATA":
                        if "word" in m.resolved:
                            live.append(m.resolved["word"])
                        history += [v for name, v, _ in m.historical if name == "word"]
                    elif m.type == "DBIRTH":
                        births.append(m.resolved.get("word"))
                return live, history, births

            def all_arrived():
                live, history, _ = values()
                return set(range(1, total + 1)) <= set(live) | set(history)
            try:
                eventually(all_arrived, 60, "every change at the host on node 2")
            except AssertionError:
                pass  # counted below, with what is missing
            eventually(lambda: self.rig.state()["sparkplug"]["store"]["records"] == 0, 60,
                       lambda: f"the store emptied: {self.rig.state()['sparkplug']['store']}")
            self.set_word(client, BARRIER)
            # in a DDATA, or in the DBIRTH of a module back online after a busy moment
            host.wait_metric(device, "word", BARRIER, since=mark, timeout=60)
            live, history, births = values()
            live = [v for v in live if v != BARRIER]
            counted = live + history
            # A DBIRTH carries its device's current value: a module that went offline under load
            # and came back (DDEATH, DBIRTH) delivered the value it came back with that way.
            lost = sorted(set(range(1, total + 1)) - set(counted) - set(births))
            duplicated = sorted({v for v in counted if counted.count(v) > 1})
            figures = {
                "broker": cluster.kind, "mode": label or mode,
                "node 1 gone": stopped[0] if stopped else float("nan"),
                "changes": total, "changes took": changed, "sparkplug": spb_seconds, "json": json_seconds,
                "live": len(set(live)), "historical": len(set(history) - set(live)),
                "lost": len(lost), "duplicated": len(duplicated), "closed": closed,
                "ndeath": [m.metric("bdSeq").value for m in host.since(mark, "NDEATH", node=NODE)
                           if m.index < nbirth.index],
                "json offline": len(json_offline),
            }
            FIGURES.append(figures)
            print(f"\n  {cluster.kind}, node 1 {figures['mode']}: node 1 gone after "
                  f"{figures['node 1 gone']:.2f} s; {total} changes in {changed:.2f} s; new "
                  f"session {'on node 2 ' if not blocked_for else ''}after {spb_seconds:.2f} s "
                  f"(Sparkplug NBIRTH) and {json_seconds:.2f} s (JSON status online); values "
                  f"live {figures['live']}, historical {figures['historical']}, lost {len(lost)} "
                  f"{lost[:10]}, duplicated {len(duplicated)} {duplicated[:10]}; the old "
                  f"session's NDEATH at the host: {figures['ndeath'] or 'none'}, its JSON status offline "
                  f"on node 2: {figures['json offline']}", file=sys.stderr)
            self.assertEqual(lost, [], "changes lost")
            # Live DDATA goes at QoS 0 (Sparkplug 3.0): what node 1 may not have read when it
            # went away (sent since the broker last proved it read everything before) is stored
            # too, and forwarded (docs/sparkplug.md, "Live data the broker may not have read").
            # What node 1 did read of it arrives twice, live then as history: only those, each
            # once of each, the changes just before the first that went to the store alone.
            only_history = sorted(set(history) - set(live))
            first_stored = only_history[0] if only_history else max(counted, default=0) + 1
            self.assertTrue(all(live.count(v) == 1 and history.count(v) == 1 for v in duplicated),
                            f"changes twice at the host, beyond live then history: {duplicated}")
            self.assertEqual(duplicated, list(range(first_stored - len(duplicated), first_stored)),
                             "changes twice at the host, not those just before the loss")
            figures["unproven read twice"] = len(duplicated)
            # the will of the session on node 1: never from a cluster's dead node; from a
            # bridged Mosquitto stopped cleanly, which publishes its clients' wills as it stops,
            # those that cross the bridge before it closes (a race: the JSON output's did not,
            # once in six runs), the old session's, never a later one
            if mode == "stop" and self.WILL_AT_STOP:
                self.assertIn(figures["ndeath"], ([born], []), "the old session's will at most")
                self.assertLessEqual(figures["json offline"], 1)
                WILLS.append((figures["ndeath"] == [born], figures["json offline"] == 1))
            else:
                self.assertEqual(figures["ndeath"], [], "the will of a session of a dead node")
                if not blocked_for:
                    self.assertEqual(figures["json offline"], 0,
                                     "the JSON output's will (status offline) on node 2")
            # the JSON side on node 2: the state current, live and retained
            ha.wait(DIM_STATE, lambda m: json.loads(m[1]).get("word") == BARRIER, ha_mark)
            last = ha.since(ha_mark, DIM_STATE)[-1]
            self.assertEqual(json.loads(last[1])["word"], BARRIER, last)
            if not blocked_for:
                kept = eventually(lambda: retained(cluster, 1, (STATUS, DIM_STATE)), 10,
                                  "the status and state retained on node 2")
                self.assertEqual(kept.get(STATUS), "online", kept)
                self.assertEqual(json.loads(kept[DIM_STATE])["word"], BARRIER, kept)
            self.ha_birth_on_node2()
        except BaseException:
            print(f"\n  the daemon's log, its end:\n{self.rig.log_text()[-6000:]}", file=sys.stderr)
            raise
        finally:
            client.close()
            ha.close()
            if not cluster.nodes[0].running():
                self.rig.stop_daemon(signal.SIGTERM)
                seconds = cluster.start_node(0)
                print(f"  {cluster.kind}: node 1 back in the cluster in {seconds:.1f} s",
                      file=sys.stderr)


    def ha_birth_on_node2(self):
        """A Home Assistant starting on node 2 (a new client) announces itself: the gateway's
        status online and dim16 0's state reach it, published again, not retained copies."""
        ha = Watcher(self.cluster, 1)
        try:
            mark = ha.mark()
            ha.publish(f"{HA}/status", "online")
            ha.wait(STATUS, lambda m: m[1] == "online" and not m[2], mark)
            ha.wait(DIM_STATE, lambda m: not m[2], mark)
        finally:
            ha.close()


class Ejabberd(FleetCase):
    """ejabberd 23.01: both outputs in MQTT 5, node-local retained messages."""

    @classmethod
    def make_cluster(cls, directory):
        return EjabberdCluster(directory)

    def test_a_home_assistant_on_node_2_sees_the_gateway_online(self):
        # The daemon on node 1: what it retains stays on node 1, and a Home Assistant that
        # starts on node 2 learns the gateway's status only from its answer to the birth.
        self.start_rig()
        # the status is retained once the JSON output published it, a moment after it connected
        eventually(lambda: retained(self.cluster, 0, (STATUS,)) == {STATUS: "online"}, 30,
                   "the gateway's status retained on node 1")
        self.assertEqual(retained(self.cluster, 1, (STATUS, DIM_STATE)), {},
                         "node 1's retained messages on node 2")
        self.ha_birth_on_node2()

    def test_a_clean_stop_of_node_1(self):
        self.failover("stop")

    def test_a_kill_of_node_1(self):
        self.failover("kill")

    def test_a_primary_host_must_publish_its_state_on_every_node(self):
        # The host's STATE is retained on node 2 only: the daemon on node 1 gets none within
        # keepalive, leaves node 1 and is born on node 2. With the STATE on node 1 as well, it
        # is born on node 1 at once.
        host_id = "fleet-scada"
        topic = f"spBv1.0/STATE/{host_id}"
        try:
            self.host.state(host_id, True)
            self.rig = FleetRig(tempfile.mkdtemp(dir=self.dir), self.cluster,
                                primary_host=host_id)
            mark = self.host.mark()
            began = time.monotonic()
            self.rig.start_daemon()
            self.rig.wait_connected("mqtt", self.url(0))
            nbirth = self.host.wait_message("NBIRTH", node=NODE, since=mark, timeout=30)
            seconds = nbirth.received - began
            nbirth_bdseq = nbirth.metric("bdSeq").value
            self.assertEqual(self.rig.state()["sparkplug"]["broker"], self.url(1))
            self.assertEqual(self.host.since(mark, "NBIRTH", node=NODE), [nbirth],
                             "births on node 1")
            # the session left on node 1 ended with NDEATH, then (MQTT 5) its will: both reach
            # the host on node 2, with the bdSeq before the NBIRTH's
            ndeaths = [m.metric("bdSeq").value for m in self.host.since(mark, "NDEATH", node=NODE)
                       if m.index < nbirth.index]
            self.assertEqual(ndeaths, [nbirth_bdseq - 1] * 2)
            # the STATE on node 1 too: a new daemon is born there
            mark = self.host.mark()
            self.rig.stop_daemon(signal.SIGTERM)
            self.host.wait_message("NDEATH", node=NODE, since=mark, timeout=60)
            watcher = Watcher(self.cluster, 0, ())
            try:
                watcher.publish(topic, json.dumps({"online": True,
                                                   "timestamp": int(time.time() * 1000)}),
                                retain=True)
            finally:
                watcher.close()
            mark = self.host.mark()
            began = time.monotonic()
            self.rig.start_daemon()
            nbirth = self.host.wait_message("NBIRTH", node=NODE, since=mark, timeout=30)
            both_seconds = nbirth.received - began
            self.assertEqual(self.rig.state()["sparkplug"]["broker"], self.url(0))
            self.assertNotIn(f"connected to {self.url(1)}", self.rig.log_text())
            print(f"\n  ejabberd, primary host's STATE on node 2 only: the daemon born on node 2 "
                  f"{seconds:.2f} s after its start (keepalive 5 s on node 1; NDEATH of the session "
                  f"left there at the host: {ndeaths}, the NBIRTH's bdSeq "
                  f"{nbirth_bdseq}); on both nodes: "
                  f"born on node 1 after {both_seconds:.2f} s", file=sys.stderr)
        finally:
            for index in range(len(self.cluster.nodes)):
                watcher = Watcher(self.cluster, index, ())
                try:
                    watcher.publish(topic, "", retain=True)
                finally:
                    watcher.close()


class RabbitMQ(FleetCase):
    """RabbitMQ 3.10 with `mqtt.sparkplug = true`, and the mirrored-queue policy (ha-mode all)
    on the MQTT plugin's queues where a test asks for it; the daemon with
    `device_id_separator: _`."""
    SEPARATOR = "_"
    mirrored = False

    @classmethod
    def make_cluster(cls, directory):
        return RabbitCluster(directory, extra_config="mqtt.sparkplug = true")

    def test_both_outputs_fall_back_to_3_1_1_and_a_dcmd_acts(self):
        self.start_rig()
        # what the daemon retains through node 1 stays on node 1
        self.assertEqual(retained(self.cluster, 0, (STATUS,)), {STATUS: "online"})
        self.assertEqual(retained(self.cluster, 1, (STATUS, DIM_STATE)), {},
                         "node 1's retained messages on node 2")
        for section in ("mqtt", "mqtt_json"):
            self.rig.wait_log(rf"{section}: {re.escape(self.url(0))} closed the connection after "
                              r"an MQTT 5 CONNECT, without a CONNACK, so MQTT 3\.1\.1 with it "
                              r"from now on", 5)
            self.assertEqual(self.rig.wait_connected(section, self.url(0)), "3.1.1")
        # the JSON side through node 1, read on node 2
        ha = Watcher(self.cluster, 1)
        try:
            mark = ha.mark()
            self.rig.ctl("set dim16:0 0x0042")
            ha.wait(DIM_STATE, lambda m: json.loads(m[1]).get("word") == 0x42, mark)
        finally:
            ha.close()
        # a DCMD from the host on node 2 to the device the daemon announced
        self.host.dcmd(GROUP, NODE, "hub0_dom16_0", [{"name": "out/1", "value": True}])
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) & 0x0002, 10,
                   lambda: f"out/1 on at the simulator; {self.rig.log_text()[-2000:]}")

    def test_commands_that_name_no_device_are_counted(self):
        self.start_rig()
        log = self.rig.log_mark()
        on = command_payload([("out/0", "Boolean", True)])
        # the default separator's device id, which RabbitMQ turns into three levels, and a
        # device the node does not have
        self.host.publish_raw(f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0.dom16.0", on)
        self.host.publish_raw(f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0_dom16_7", on)
        self.rig.wait_log(rf"Sparkplug: a DCMD on spBv1\.0/{GROUP}/DCMD/{NODE}/hub0/dom16/0, "
                          r"which names no device of this edge node \(its device id has several "
                          r"levels", 10, log)
        eventually(lambda: re.search(r'(?m)^ioportd_sparkplug_commands_total\{result='
                                     r'"unknown_device"\} 2$', self.rig.metrics()), 10,
                   lambda: self.rig.metrics())
        self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0001, 0)
        # the host itself got its own DCMD of several levels back: outside Sparkplug's topics
        self.host_violations_allowed.append(r"^\[topic\] topic outside the Sparkplug namespace: "
                                            rf"spBv1\.0/{GROUP}/DCMD/{NODE}/hub0/dom16/0$")

    def test_failover_a_clean_stop_of_node_1(self):
        self.policy(False)
        self.failover("stop")

    def test_failover_a_kill_of_node_1_blocks_it_without_the_mirrored_policy(self):
        # The queue of the daemon's subscriptions lives on node 1; dead, it cannot be declared
        # again on node 2, which closes the connection at the SUBSCRIBE, again and again.
        self.policy(False)
        self.failover("kill", "kill, no policy: until node 1 is back", blocked_for=15)

    def test_failover_a_kill_of_node_1_with_the_mirrored_policy(self):
        self.policy(True)
        self.failover("kill", "kill (ha-mode all)")

    def set_max_message_size(self, size):
        """RabbitMQ's max_message_size (rabbitmq.conf), on both nodes: a channel reads it when
        it opens, so it holds for the MQTT connections made from now on."""
        for node in self.cluster.nodes:
            self.cluster._ctl_ok(node, "eval",
                                 f"application:set_env(rabbit, max_message_size, {size}).")

    def test_max_message_size_65536_keeps_a_dcmd_over_64_kib_from_the_daemon(self):
        self.set_max_message_size(65536)
        try:
            self.start_rig()
            log = self.rig.log_mark()
            # RabbitMQ 3.10 fails the publish on the connection's channel: no PUBACK, and the
            # connection stays open
            self.assertEqual(publish_once(self.cluster, 1, f"spBv1.0/{GROUP}/DCMD/{NODE}/"
                                          "hub0_dom16_0", big_dcmd()), "unanswered")
            self.host.dcmd(GROUP, NODE, "hub0_dom16_0", [{"name": "out/2", "value": True}])
            eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) & 0x0004, 10, "out/2 on")
            self.assertNotIn("refused", self.rig.log_text()[log:])
        finally:
            self.set_max_message_size(DEFAULT_MAX_MESSAGE_SIZE)

    def test_a_birth_over_max_message_size_ends_the_session_each_time(self):
        # 320 bytes: the NBIRTH passes, a DBIRTH (about 400 bytes) not
        self.host_violations_allowed.append(
            r"^\[nbirth\] .*NBIRTH bdSeq \d+ while the session of bdSeq \d+ had no NDEATH$")
        self.set_max_message_size(320)
        try:
            self.rig = FleetRig(tempfile.mkdtemp(dir=self.dir), self.cluster, self.SEPARATOR)
            mark = self.host.mark()
            self.rig.start_daemon()
            # each session ends at once: the back-off goes on doubling (1 s each time before)
            closed = r"(?m)^.* mqtt: .*; reconnecting within (\d+) s$"
            began = time.monotonic()
            eventually(lambda: len(re.findall(closed, self.rig.log_text())) >= 3, 30,
                       lambda: self.rig.log_text()[-3000:])
            seconds = time.monotonic() - began
            delays = [int(delay) for delay in re.findall(closed, self.rig.log_text())]
            self.assertEqual(delays[:3], [1, 2, 4], self.rig.log_text()[-3000:])
            nbirths = self.host.since(mark, "NBIRTH", node=NODE)
            print(f"\n  RabbitMQ, max_message_size 320: {len(delays)} sessions closed in "
                  f"{seconds:.1f} s, each followed by a reconnect within {delays} s; at the host "
                  f"{len(nbirths)} NBIRTH (bdSeq {[m.metric('bdSeq').value for m in nbirths]}), "
                  f"{len(self.host.since(mark, 'NDEATH', node=NODE))} NDEATH, "
                  f"{len(self.host.since(mark, 'DBIRTH'))} DBIRTH", file=sys.stderr)
            self.assertEqual(self.host.since(mark, "DBIRTH"), [], "a DBIRTH through the limit")
            self.assertEqual(self.host.since(mark, "NDEATH", node=NODE), [],
                             "the will of a session RabbitMQ closed")
        finally:
            self.set_max_message_size(DEFAULT_MAX_MESSAGE_SIZE)
        # the limit raised: the next session's births go through (the next try within 8 s)
        nbirth = self.host.wait_message("NBIRTH", node=NODE, since=mark, timeout=30,
                                        where=lambda m: self.host.since(m.index, "DBIRTH"))
        self.assertIsNotNone(nbirth)

    def policy(self, mirrored):
        if mirrored != self.mirrored:
            self.cluster.set_policy() if mirrored else self.cluster.clear_policy()
            type(self).mirrored = mirrored


def big_dcmd():
    """A DCMD to dom16 0 of 8000 `out/0` metrics: about 88 KB, beyond the 64 KiB the daemon
    takes (its MQTT 5 Maximum Packet Size, its MQTT 3.1.1 relay's bound)."""
    payload = command_payload([("out/0", "Boolean", True)] * 8000)
    assert len(payload) > 65536, len(payload)
    return payload


def publish_once(cluster, index, topic, payload):
    """`payload` published at QoS 1 by a new MQTT 3.1.1 client on node `index`: "acked" when
    the node acknowledged it, "closed" when the node closed the connection instead, and
    "unanswered" when neither came within 5 s (a PUBACK takes milliseconds here)."""
    client = mqtt.Client(f"big-{time.monotonic_ns()}", clean_session=True,
                         protocol=mqtt.MQTTv311)
    if cluster.credentials:
        client.username_pw_set(*cluster.credentials)
    connected, closed, acked = threading.Event(), threading.Event(), threading.Event()
    client.on_connect = lambda _c, _u, _f, rc: rc == 0 and connected.set()
    client.on_disconnect = lambda *_: closed.set()
    client.on_publish = lambda *_: acked.set()
    client.connect("127.0.0.1", cluster.nodes[index].mqtt_port, keepalive=30)
    client.loop_start()
    try:
        eventually(connected.is_set, 10, f"CONNACK from node {index + 1}")
        client.publish(topic, payload, qos=1)
        try:
            eventually(lambda: acked.is_set() or closed.is_set(), 5,
                       f"PUBACK or a close from node {index + 1}")
        except AssertionError:
            return "unanswered"
        return "acked" if acked.is_set() else "closed"
    finally:
        client.disconnect()
        client.loop_stop()


class EjabberdSizes(unittest.TestCase):
    """ejabberd's bound on a PUBLISH (mod_mqtt's listener option max_payload_size), each test
    on a one-node ejabberd of its own: what the daemon's messages meet over it, and what it
    keeps from the daemon under it."""
    DCMD = f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0.dom16.0"

    def start(self, max_payload_size=None):
        self.dir = tempfile.mkdtemp(prefix="ioportd-fleet-size-")
        options = {"max_payload_size": max_payload_size} if max_payload_size else {}
        self.cluster = EjabberdCluster(os.path.join(self.dir, "cluster"), size=1,
                                       listener_options=options)
        self.cluster.start()  # ClusterError: a failure, never a skip
        self.host = HostApp(self.cluster.nodes[0].mqtt_port, client_id="size-host",
                            credentials=self.cluster.credentials)
        self.rig = FleetRig(tempfile.mkdtemp(dir=self.dir), self.cluster)
        self.rig.start_daemon()

    def tearDown(self):
        for name in ("rig", "host", "cluster"):
            if hasattr(self, name):
                getattr(self, name).close()
        shutil.rmtree(self.dir, ignore_errors=True)

    def born(self):
        nbirth = self.host.wait_message("NBIRTH", node=NODE, timeout=60)
        self.host.wait_message("DBIRTH", "hub0.dom16.0", since=nbirth.index, timeout=60)

    def refused_commands(self):
        found = re.search(r'(?m)^ioportd_sparkplug_commands_total\{result="refused"\} (\d+)$',
                          self.rig.metrics())
        return int(found.group(1)) if found else 0

    def test_by_default_a_dcmd_over_64_kib_reaches_the_daemon(self):
        # The daemon's CONNECT asks for packets of 64 KiB at most (MQTT 5's Maximum Packet
        # Size): ejabberd 23.01 sends it a larger one all the same.
        self.start()
        self.born()
        self.assertEqual(publish_once(self.cluster, 0, self.DCMD, big_dcmd()), "acked")
        self.rig.wait_log(r"Sparkplug DCMD to hub0\.dom16\.0 refused: ", 10)
        self.assertEqual(self.refused_commands(), 1)

    def test_max_payload_size_65536_keeps_it_from_the_daemon(self):
        self.start(65536)
        self.born()
        log = self.rig.log_mark()
        self.assertEqual(publish_once(self.cluster, 0, self.DCMD, big_dcmd()), "closed")
        # the daemon goes on, and a DCMD after it acts
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"name": "out/1", "value": True}])
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) & 0x0002, 10, "out/1 on")
        self.assertNotIn("refused", self.rig.log_text()[log:])
        self.assertEqual(self.refused_commands(), 0)
        self.assertNotIn("closed the connection", self.rig.log_text())
        self.assertNotIn("sent DISCONNECT", self.rig.log_text())

    def test_a_birth_over_max_payload_size_ends_the_session_each_time(self):
        # 320 bytes: the NBIRTH (about 280 with its topic) passes, a DBIRTH (about 400) not.
        # Each session ends at once, so the daemon's back-off goes on doubling (it was 1 s
        # each time, for ever), and the journal names the message that was too large.
        self.start(320)
        disconnect = rf"(?m)^.* mqtt: {re.escape(self.rig.urls[0])} sent DISCONNECT: Packet " \
                     r"too large \(reason code 0x95\); the largest message of this session " \
                     r"had (\d+) bytes \((\S+)\): raise the broker's limit on a message's " \
                     r"size above it \(ejabberd: max_payload_size\); reconnecting within " \
                     r"(\d+) s$"
        began = time.monotonic()
        eventually(lambda: len(re.findall(disconnect, self.rig.log_text())) >= 3, 30,
                   lambda: self.rig.log_text()[-3000:])
        seconds = time.monotonic() - began
        ends = re.findall(disconnect, self.rig.log_text())
        delays = [int(delay) for _, _, delay in ends]
        self.assertEqual(delays[:3], [1, 2, 4], ends)
        for size, topic, _ in ends:
            self.assertGreater(int(size), 320, ends)
            self.assertRegex(topic, rf"^spBv1\.0/{GROUP}/DBIRTH/{NODE}/", ends)
        nbirths = self.host.since(0, "NBIRTH", node=NODE)
        ndeaths = self.host.since(0, "NDEATH", node=NODE)
        print(f"\n  ejabberd, max_payload_size 320: {len(delays)} sessions ended by DISCONNECT "
              f"0x95 in {seconds:.1f} s, each followed by a reconnect within {delays} s; at the "
              f"host {len(nbirths)} NBIRTH (bdSeq {[m.metric('bdSeq').value for m in nbirths]}), "
              f"{len(ndeaths)} NDEATH, {len(self.host.since(0, 'DBIRTH'))} DBIRTH",
              file=sys.stderr)
        self.assertEqual(self.host.since(0, "DBIRTH"), [], "a DBIRTH through the limit")
        # each session's will published: the host sees the node die each time
        eventually(lambda: len(self.host.since(0, "NDEATH", node=NODE)) >= len(delays) - 1, 5,
                   "an NDEATH per session")


class MosquittoBridge(FleetCase):
    """Two Mosquitto 2.0 brokers, node 1 bridged to node 2 (a `connection` on node 1 carrying
    spBv1.0/#, the JSON output's ioportd/# and homeassistant/# both ways): the daemon on node 1,
    the host on node 2 gets it through the bridge."""

    WILL_AT_STOP = True

    @classmethod
    def make_cluster(cls, directory):
        return BridgedMosquitto(directory)

    def test_retained_messages_cross_the_bridge(self):
        self.start_rig()
        kept = eventually(lambda: retained(self.cluster, 1, (STATUS, DIM_STATE)), 10,
                          "node 1's retained messages on node 2")
        self.assertEqual(kept.get(STATUS), "online", kept)
        self.ha_birth_on_node2()

    def test_a_clean_stop_of_node_1(self):
        self.failover("stop")

    def test_a_kill_of_node_1(self):
        self.failover("kill")


def print_figures():
    if not FIGURES:
        return
    print("\nFailover figures (seconds from node 1's stop or kill to the new session; the "
          "values of the changes at the host on node 2):", file=sys.stderr)
    print("| broker | node 1 | Sparkplug | JSON | changes | live | historical | lost | "
          "duplicated |", file=sys.stderr)
    print("|---|---|---|---|---|---|---|---|---|", file=sys.stderr)
    for f in FIGURES:
        print(f"| {f['broker']} | {f['mode']} | {f['sparkplug']:.2f} | {f['json']:.2f} | "
              f"{f['changes']} | {f['live']} | {f['historical']} | {f['lost']} | "
              f"{f['duplicated']} |", file=sys.stderr)
    for ndeath, offline in WILLS:
        print(f"Mosquitto bridge, clean stop of node 1: the Sparkplug will crossed the bridge: "
              f"{ndeath}; the JSON output's: {offline}", file=sys.stderr)


def tearDownModule():
    print_figures()


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1] + sys.argv[4:], verbosity=2)
