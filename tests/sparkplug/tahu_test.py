"""ioportd read and commanded by a host built on Eclipse Tahu, Sparkplug's reference
implementation: its `sparkplug-payload` library and the `mqtt` client from npm (tahu/host.js),
against a real mosquitto, the real simulators and the real daemon (issue 49). Tahu decodes every
message ioportd publishes (births with every metric of edge_node_test.py's table, data, the
will after kill -9) and ioportd acts on the NCMD and DCMD that Tahu encodes. The rules of the
specification themselves are edge_node_test.py's; here the question is whether the reference
library reads and writes what ioportd does.

Usage: tahu_test.py IOPORTD IOPORT_SIM PYTHON_DIR TAHU_DIR [tests]
       tahu_test.py install TAHU_DIR     # npm ci of tests/sparkplug/tahu/ into TAHU_DIR, once
                                         # per lock file
"""
import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))

import npm  # noqa: E402

if __name__ == "__main__" and sys.argv[1:2] == ["install"]:
    if len(sys.argv) != 3:
        sys.exit("usage: tahu_test.py install TAHU_DIR")
    npm.install(os.path.join(HERE, "tahu"), sys.argv[2],
                os.path.join("node_modules", "sparkplug-payload", "index.js"))
    sys.exit(0)

# edge_node_test.py reads IOPORTD, IOPORT_SIM and PYTHON_DIR from the same three arguments.
from edge_node_test import GROUP, METRICS, NODE, EdgeNodeRig  # noqa: E402
from broker import Broker  # noqa: E402
from rig import die_with_parent, eventually  # noqa: E402

TAHU_DIR = sys.argv[4]


class TahuHost:
    """tahu/host.js on the broker: every message as Tahu decoded it, in order, a data message's
    metrics named by the aliases of the last birth (as a host does); `send` has Tahu encode a
    command."""

    def __init__(self, broker_port):
        npm.install(os.path.join(HERE, "tahu"), TAHU_DIR,
                    os.path.join("node_modules", "sparkplug-payload", "index.js"))
        self.messages = []
        self.lock = threading.Lock()
        self.subscribed = threading.Event()
        self.errors = queue.SimpleQueue()
        self.process = subprocess.Popen(
            ["node", os.path.join(HERE, "tahu", "host.js"), str(broker_port)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            env=dict(os.environ, NODE_PATH=os.path.join(TAHU_DIR, "node_modules")),
            preexec_fn=die_with_parent)
        threading.Thread(target=self.read, daemon=True).start()
        threading.Thread(target=self.read_errors, daemon=True).start()
        eventually(self.subscribed.is_set, 20, lambda: f"Tahu's host subscribed "
                   f"(exit {self.process.poll()}): {self.stderr_text()}")

    def read(self):
        aliases = {}  # of each node and device, from its last birth, as a host keeps them
        for line in self.process.stdout:
            message = json.loads(line)
            if message.get("subscribed"):
                self.subscribed.set()
                continue
            parts = message["topic"].split("/")
            kind, source = parts[2], tuple(parts[3:])
            named = aliases.setdefault(source, {})
            for metric in message.get("payload", {}).get("metrics", []):
                if kind in ("NBIRTH", "DBIRTH") and "alias" in metric:
                    named[metric["alias"]] = metric["name"]
                elif "name" not in metric and "alias" in metric:
                    metric["name"] = named.get(metric["alias"], f"alias {metric['alias']}")
            with self.lock:
                self.messages.append(message)

    def read_errors(self):
        for line in self.process.stderr:
            self.errors.put(line)

    def stderr_text(self):
        lines = []
        while not self.errors.empty():
            lines.append(self.errors.get())
        return "".join(lines)

    def mark(self):
        with self.lock:
            return len(self.messages)

    def wait(self, kind, device=None, since=0, condition=lambda payload: True, timeout=10):
        """The first message of `kind` (NBIRTH, DDATA...) of ioportd's node and `device` after
        `since` that Tahu decoded and that meets `condition`."""
        topic = f"spBv1.0/{GROUP}/{kind}/{NODE}" + (f"/{device}" if device else "")
        found = []

        def arrived():
            with self.lock:
                for message in self.messages[since:]:
                    if message["topic"] == topic:
                        self.assert_decoded(message)
                        if condition(message["payload"]):
                            found.append(message["payload"])
                            return True
            return False
        eventually(arrived, timeout, lambda: f"{topic} decoded by Tahu; Tahu saw "
                   f"{[m['topic'] for m in self.messages[since:]][-20:]} {self.stderr_text()}")
        return found[0]

    @staticmethod
    def assert_decoded(message):
        if "error" in message:
            raise AssertionError(f"Tahu could not decode {message['topic']}: {message['error']}")

    def send(self, topic, payload):
        self.process.stdin.write(json.dumps({"topic": topic, "payload": payload}) + "\n")
        self.process.stdin.flush()

    def close(self):
        self.process.stdin.close()
        try:
            self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def metrics(payload):
    return {m["name"]: m for m in payload.get("metrics", [])}


def ids(payload):
    return {m["name"]: m["type"] for m in payload.get("metrics", [])}


class TahuCase(unittest.TestCase):
    """A broker, Tahu's host and a daemon (with MQTT_EXTRA under mqtt:) for the class; the daemon
    started again for the next test when one killed it."""
    MQTT_EXTRA = ""

    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="ioportd-tahu-")
        cls.broker = Broker(cls.dir)
        cls.broker.start()
        cls.host = TahuHost(cls.broker.port)
        cls.rig = None

    @classmethod
    def tearDownClass(cls):
        if cls.rig:
            cls.rig.close()
        cls.host.close()
        cls.broker.stop()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def setUp(self):
        if self.rig is None or self.rig.daemon.poll() is not None:
            if self.rig:
                self.rig.close()
            type(self).rig = EdgeNodeRig(tempfile.mkdtemp(dir=self.dir), self.broker.port,
                                         mqtt_extra=self.MQTT_EXTRA)
            self.rig.ctl("set dim16:0 0x0005")
            mark = self.host.mark()
            self.rig.start_daemon()
            type(self).nbirth = self.host.wait("NBIRTH", since=mark)
            type(self).births = mark


class Tahu(TahuCase):
    def test_tahu_decodes_every_birth_with_the_metrics_and_types_ioportd_announces(self):
        node = metrics(self.nbirth)
        self.assertEqual(node["Node Control/Rebirth"]["type"], "Boolean")
        self.assertFalse(node["Node Control/Rebirth"]["value"])
        self.assertEqual(node["bdSeq"]["type"], "Int64")
        for device, expected in METRICS.items():
            if device == "hub0.mux8m.0":  # not configured in EdgeNodeRig's hub
                continue
            birth = self.host.wait("DBIRTH", device, since=self.births)
            got = ids(birth)
            for name, kind in expected:
                self.assertEqual(got.get(name), kind, f"{device} {name}: {got}")
        dim16 = metrics(self.host.wait("DBIRTH", "hub0.dim16.0", since=self.births))
        self.assertEqual(dim16["word"]["value"], 5)
        self.assertEqual([dim16[f"in/{k}"]["value"] for k in range(4)],
                         [True, False, True, False])

    def test_tahu_decodes_ddata_of_a_changed_input(self):
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x8001")
        data = self.host.wait("DDATA", "hub0.dim16.0", since=mark,
                              condition=lambda p: metrics(p).get("word", {}).get("value") == 0x8001)
        changed = metrics(data)
        self.assertTrue(changed["in/15"]["value"])
        self.assertEqual(changed["word"]["type"], "UInt16")
        self.assertIn("timestamp", changed["word"])

    def test_a_dcmd_that_tahu_encodes_sets_the_output(self):
        mark = self.host.mark()
        self.host.send(f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0.dom16.0", {
            "timestamp": int(time.time() * 1000),
            "metrics": [{"name": "out/3", "type": "Boolean", "value": True},
                        {"name": "out/9", "type": "Boolean", "value": True}]})
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) == 0x0208, 10,
                   lambda: f"dom16:0 = {self.rig.ctl('get dom16:0')}; {self.rig.log_text()[-2000:]}")
        for name, value in (("out/3", True), ("out/9", True), ("word", 0x0208)):
            self.host.wait("DDATA", "hub0.dom16.0", since=mark,
                           condition=lambda p: metrics(p).get(name, {}).get("value") == value)
        # By the alias of the DBIRTH, without a name.
        birth = metrics(self.host.wait("DBIRTH", "hub0.dom16.0", since=self.births))
        self.host.send(f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0.dom16.0", {
            "timestamp": int(time.time() * 1000),
            "metrics": [{"alias": int(birth["out/5"]["alias"]), "type": "Boolean",
                         "value": True}]})
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) == 0x0228, 10,
                   lambda: f"dom16:0 = {self.rig.ctl('get dom16:0')}")
        # And a whole word, UInt16, back to nothing.
        self.host.send(f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0.dom16.0", {
            "timestamp": int(time.time() * 1000),
            "metrics": [{"name": "word", "type": "UInt16", "value": 0}]})
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) == 0, 10,
                   lambda: f"dom16:0 = {self.rig.ctl('get dom16:0')}")

    def test_an_ncmd_rebirth_that_tahu_encodes_gives_births_with_the_same_bdseq(self):
        mark = self.host.mark()
        self.host.send(f"spBv1.0/{GROUP}/NCMD/{NODE}", {
            "timestamp": int(time.time() * 1000),
            "metrics": [{"name": "Node Control/Rebirth", "type": "Boolean", "value": True}]})
        again = self.host.wait("NBIRTH", since=mark)
        self.assertEqual(metrics(again)["bdSeq"]["value"],
                         metrics(self.nbirth)["bdSeq"]["value"])
        self.host.wait("DBIRTH", "hub0.dom16.0", since=mark)

    def test_z_the_will_after_kill_9_is_decoded_with_the_sessions_bdseq(self):
        # Last in the class (by name): the daemon is killed; a test after it starts another.
        bdseq = metrics(self.nbirth)["bdSeq"]["value"]
        mark = self.host.mark()
        self.rig.daemon.send_signal(signal.SIGKILL)
        self.rig.daemon.wait()
        # The broker publishes the will once the keepalive (5 s) and its grace have passed.
        death = self.host.wait("NDEATH", since=mark, timeout=20)
        self.assertEqual(metrics(death)["bdSeq"]["value"], bdseq)
        self.assertEqual(metrics(death)["bdSeq"]["type"], "Int64")


class TahuTemplates(TahuCase):
    """With templates (gateway.md §7.2): the definitions in NBIRTH, an instance per module, its
    changed members in DDATA, and a DCMD to an instance's member, all through Tahu."""
    MQTT_EXTRA = "  templates: true\n"

    def test_tahu_decodes_the_definitions_and_each_instance(self):
        node = metrics(self.nbirth)
        for device, expected in METRICS.items():
            if device == "hub0.mux8m.0":
                continue
            kind = device.split(".")[1]
            definition = node[f"_types_/{kind}"]
            self.assertEqual(definition["type"], "Template")
            self.assertTrue(definition["value"]["isDefinition"])
            self.assertEqual(definition["value"]["version"], "1")
            self.assertEqual(ids(definition["value"]), dict(expected), kind)
            instance = metrics(self.host.wait("DBIRTH", device, since=self.births))[kind]
            self.assertEqual((instance["type"], instance["value"]["templateRef"]),
                             ("Template", kind))
            self.assertFalse(instance["value"]["isDefinition"])
            self.assertEqual(set(ids(instance["value"])), {name for name, _ in expected})
        dim16 = metrics(self.host.wait("DBIRTH", "hub0.dim16.0", since=self.births))["dim16"]
        self.assertEqual(metrics(dim16["value"])["word"]["value"], 5)

    def test_tahu_decodes_the_members_that_changed(self):
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x8001")

        def word_of(payload):
            instance = metrics(payload).get("dim16", {}).get("value", {})
            return metrics(instance).get("word", {}).get("value")
        data = self.host.wait("DDATA", "hub0.dim16.0", since=mark,
                              condition=lambda p: word_of(p) == 0x8001)
        members = metrics(metrics(data)["dim16"]["value"])
        self.assertEqual(members["word"]["type"], "UInt16")
        self.assertTrue(members["in/15"]["value"])

    def test_a_dcmd_to_an_instance_member_that_tahu_encodes_sets_the_output(self):
        self.host.send(f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0.dom16.0", {
            "timestamp": int(time.time() * 1000),
            "metrics": [{"name": "dom16", "type": "Template", "value": {
                "templateRef": "dom16", "isDefinition": False,
                "metrics": [{"name": "out/3", "type": "Boolean", "value": True}]}}]})
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) == 0x0008, 10,
                   lambda: f"dom16:0 = {self.rig.ctl('get dom16:0')}; {self.rig.log_text()[-2000:]}")


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1] + sys.argv[5:], verbosity=2)
