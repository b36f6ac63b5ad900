#!/usr/bin/python3
"""ioportd's plain MQTT output with Home Assistant discovery (gateway.md §6.3, issue 28), end to
end: a real mosquitto broker on a free loopback port, the real simulators on ptys, the real
daemon, and a subscriber (paho-mqtt) that records every message with its retain flag. Node-RED,
when it has been installed (tests/mqtt_json/node_red.py), runs a flow of its own against the
same broker: it reads a state topic and publishes a set, and asks bridge/request/health_check
with a transaction and takes the answer that echoes it.

Usage: mqtt_json_test.py IOPORTD IOPORT_SIM [NODE_RED_DIR [TEST ...]]
  NODE_RED_DIR: where Node-RED is (or is first installed, npm ci of tests/mqtt_json/node-red/);
  without it the Node-RED test is skipped.
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

IOPORTD, IOPORT_SIM = sys.argv[1], sys.argv[2]
NODE_RED_DIR = sys.argv[3] if len(sys.argv) > 3 else ""
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))

import paho.mqtt.client as mqtt  # noqa: E402

import node_red  # noqa: E402
from broker import Broker  # noqa: E402
from process_memory import RSS_TELLS, MemoryLimit, peak_rss  # noqa: E402
from raw_mqtt import Mqtt311Broker, RawClient, ScriptedBroker, read_packet  # noqa: E402
from rig import SLOWDOWN, Rig, eventually  # noqa: E402

PREFIX = "ioportd/box7"
NODE = "ioportd_box7"  # mqtt_json::node_id(PREFIX)
HA = "homeassistant"
HUB = "dim16:0,dom16:0,acm3p:0,rgbdm:0,mux8m:0"

# Every module's Home Assistant entities as gateway.md §6.3 lists them: component -> object ids.
ENTITIES = {
    "hub0_dim16_0": {"binary_sensor": [f"in{k}" for k in range(16)]},
    "hub0_dom16_0": {"switch": [f"out{k}" for k in range(16)]},
    "hub0_acm3p_0": {"sensor": ["value0", "value1", "value2"]},
    "hub0_rgbdm_0": {"select": ["colour"]},
    "hub0_mux8m_0": {"number": ["pos", "neg"]},
    "press_id2": {"binary_sensor": ["stop"], "sensor": ["count"], "button": ["reset"]},
}


class Message:
    def __init__(self, index, topic, payload, retain):
        self.index, self.topic, self.payload, self.retain = index, topic, payload, retain

    def json(self):
        return json.loads(self.payload)


class Subscriber:
    """An MQTT client that records every message of `topics` in arrival order."""

    def __init__(self, port, topics=("#",), client_id="test-subscriber"):
        self.messages = []
        self.lock = threading.Lock()
        self.client = mqtt.Client(client_id=client_id, clean_session=True)
        self.client.on_message = self._message
        subscribed = threading.Event()
        self.client.on_subscribe = lambda *_: subscribed.set()
        self.client.connect("127.0.0.1", port, keepalive=30)
        self.client.loop_start()
        self.client.subscribe([(t, 1) for t in topics])
        assert subscribed.wait(10), "no SUBACK"

    def _message(self, _client, _userdata, m):
        with self.lock:
            self.messages.append(Message(len(self.messages), m.topic,
                                         m.payload.decode("utf-8", "replace"), bool(m.retain)))

    def mark(self):
        with self.lock:
            return len(self.messages)

    def since(self, mark=0, topic=None):
        with self.lock:
            return [m for m in self.messages[mark:] if topic is None or m.topic == topic]

    def wait(self, topic, where=lambda m: True, since=0, timeout=10):
        def found():
            return next((m for m in self.since(since, topic) if where(m)), None)
        return eventually(found, timeout, lambda: f"{topic} since {since}: " +
                          repr([(m.topic, m.payload) for m in self.since(since)][-10:]))

    def latest(self, topic):
        found = self.since(0, topic)
        return found[-1] if found else None

    def publish(self, topic, payload, retain=False):
        self.client.publish(topic, payload, qos=1, retain=retain).wait_for_publish()

    def close(self):
        self.client.loop_stop()
        self.client.disconnect()


def retained(port, pattern):
    """What the broker keeps under `pattern` now: a fresh subscriber's retained messages. The
    broker queues them when it takes the SUBSCRIBE, so a message the subscriber publishes after
    the SUBACK, to a topic of its own, arrives after the last of them."""
    barrier = f"test/barrier/{time.monotonic_ns()}"
    sub = Subscriber(port, (pattern, barrier), client_id=f"retained-{time.monotonic_ns()}")
    try:
        sub.publish(barrier, "end")
        end = sub.wait(barrier)
        return {m.topic: m.payload for m in sub.since()[:end.index] if m.retain}
    finally:
        sub.close()


class JsonRig(Rig):
    def __init__(self, directory, broker_port, hub_modules=HUB, json_extra="", modbus_extra=""):
        super().__init__(directory, IOPORTD, IOPORT_SIM)
        self.broker_port = broker_port
        try:
            self.start_hub(HUB)
            self.start_id2()
        except BaseException:
            self.close()
            raise
        self.configure(hub_modules, json_extra, modbus_extra)

    def configure(self, hub_modules, json_extra="", modbus_extra=""):
        modules = "\n".join(f"      - {{ type: {m.split(':')[0]}, number: {m.split(':')[1]}"
                            + (', name: "boiler 1", channels: { 0: { name: "supply '
                               'temperature", unit: "°C", scale: [0, 100, -20, 150] } }'
                               if m == "acm3p:0" else "")
                            + (', inputs: { 5: "pump running" }' if m == "dim16:0" else "")
                            + " }" for m in hub_modules.split(","))
        self.write_config(f"""modbus:
  listen: "127.0.0.1:0"
{modbus_extra}http:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {self.hub_link}
    unit_id: 1
    timeout: 100ms
    modules:
{modules}
  - name: press
    protocol: id2
    device: {self.id2_link}
    unit_id: 2
mqtt_json:
  broker: "mqtt://127.0.0.1:{self.broker_port}"
  topic_prefix: "{PREFIX}"
  keepalive: 5s
{json_extra}""")


def topic(module, leaf):
    return f"{PREFIX}/{module}/{leaf}"


class JsonCase(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="ioportd-json-")
        cls.broker = Broker(cls.dir)
        cls.broker.start()
        cls.sub = Subscriber(cls.broker.port)
        cls.rig = None

    @classmethod
    def tearDownClass(cls):
        if cls.rig:
            cls.rig.close()
        cls.sub.close()
        cls.broker.stop()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def new_rig(self, **kwargs):
        return JsonRig(tempfile.mkdtemp(dir=self.dir), self.broker.port, **kwargs)

    def wait_online(self, rig, since=0):
        """The daemon is online and every module's state is out."""
        self.sub.wait(f"{PREFIX}/status", lambda m: m.payload == "online", since)
        for module in ("hub0/dim16_0", "hub0/dom16_0", "hub0/acm3p_0", "press/id2"):
            self.sub.wait(topic(module, "state"), since=since)

    def ask(self, name, payload, retain=False):
        """A bridge request (gateway.md §7.3) and its answer, which is not retained."""
        mark = self.sub.mark()
        self.sub.publish(f"{PREFIX}/bridge/request/{name}", payload, retain)
        answer = self.sub.wait(f"{PREFIX}/bridge/response/{name}", since=mark)
        self.assertFalse(answer.retain)
        return answer.json()


class Output(JsonCase):
    """One daemon for the class."""

    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        cls.rig = JsonRig(tempfile.mkdtemp(dir=cls.dir), cls.broker.port)
        cls.rig.ctl("set dim16:0 0x0005")
        cls.rig.ctl("set acm3p:0 0 32768 65535")
        cls.rig.ctl("set count 7", cls.rig.id2_ctl)
        cls.rig.start_daemon()

    def setUp(self):
        self.wait_online(self.rig)

    def test_discovery_configs_are_retained_and_complete_for_every_module_type(self):
        configs = retained(self.broker.port, f"{HA}/#")
        gateway = json.loads(configs[f"{HA}/binary_sensor/{NODE}/connection/config"])
        self.assertEqual(gateway["state_topic"], f"{PREFIX}/status")
        self.assertEqual(gateway["device"]["identifiers"], [NODE])
        unique_ids = set()
        for device, components in ENTITIES.items():
            for component, points in components.items():
                for point in points:
                    name = f"{HA}/{component}/{NODE}/{device}_{point}/config"
                    self.assertIn(name, configs)
                    config = json.loads(configs[name])
                    unique_ids.add(config["unique_id"])
                    self.assertEqual(config["unique_id"], f"{NODE}_{device}_{point}")
                    self.assertEqual(config["device"]["identifiers"], [f"{NODE}_{device}"])
                    self.assertEqual(config["device"]["manufacturer"], "iomlogic")
                    self.assertEqual(config["device"]["via_device"], NODE)
                    self.assertIn(config["device"]["model"],
                                  ("dim16", "dom16", "acm3p", "rgbdm", "mux8m", "ID-2"))
                    self.assertEqual([a["topic"] for a in config["availability"]],
                                     [f"{PREFIX}/status",
                                      topic(device.replace("_", "/", 1), "availability")])
                    if component != "button":
                        self.assertEqual(config["state_topic"],
                                         topic(device.replace("_", "/", 1), "state"))
                        self.assertIn(f"value_json.{point}", config["value_template"])
                    if component in ("switch", "select", "number", "button"):
                        self.assertEqual(config["command_topic"],
                                         topic(device.replace("_", "/", 1), f"{point}/set"))
        self.assertEqual(len(unique_ids), sum(len(p) for c in ENTITIES.values()
                                              for p in c.values()))
        # names and units of gateway.md §6.1
        supply = json.loads(configs[f"{HA}/sensor/{NODE}/hub0_acm3p_0_value0/config"])
        self.assertEqual((supply["name"], supply["unit_of_measurement"], supply["device_class"],
                          supply["state_class"], supply["device"]["name"]),
                         ("supply temperature", "°C", "temperature", "measurement", "boiler 1"))
        pump = json.loads(configs[f"{HA}/binary_sensor/{NODE}/hub0_dim16_0_in5/config"])
        self.assertEqual(pump["name"], "pump running")
        count = json.loads(configs[f"{HA}/sensor/{NODE}/press_id2_count/config"])
        self.assertEqual(count["state_class"], "total_increasing")
        colour = json.loads(configs[f"{HA}/select/{NODE}/hub0_rgbdm_0_colour/config"])
        self.assertEqual(colour["options"][:3], ["off", "red", "green"])

    def test_status_availability_and_state_are_retained(self):
        kept = retained(self.broker.port, f"{PREFIX}/#")
        self.assertEqual(kept[f"{PREFIX}/status"], "online")
        for module in ("hub0/dim16_0", "hub0/dom16_0", "hub0/acm3p_0", "hub0/rgbdm_0",
                       "hub0/mux8m_0", "press/id2"):
            self.assertEqual(kept[topic(module, "availability")], "online", module)
            self.assertIn(topic(module, "state"), kept)
        acm = json.loads(kept[topic("hub0/acm3p_0", "state")])
        self.assertEqual((acm["raw0"], acm["raw2"]), (0, 65535))
        self.assertAlmostEqual(acm["value0"], -20)   # scaled as §6.1 says
        self.assertAlmostEqual(acm["value2"], 100)   # unscaled: percent
        self.assertEqual(json.loads(kept[topic("press/id2", "state")])["count"],
                         int(self.rig.ctl("get count", self.rig.id2_ctl)))

    def test_a_changed_input_reaches_the_state_topic(self):
        mark = self.sub.mark()
        self.rig.ctl("set dim16:0 0x0125")
        state = self.sub.wait(topic("hub0/dim16_0", "state"),
                              lambda m: m.json()["word"] == 0x0125, mark)
        document = state.json()
        self.assertEqual([document[f"in{k}"] for k in (0, 1, 5, 8)], [True, False, True, True])

    def test_set_on_a_dom16_output_reaches_the_device_then_the_state(self):
        mark, log = self.sub.mark(), self.rig.log_mark()
        before = int(self.rig.ctl("get dom16:0"), 0)
        self.sub.publish(topic("hub0/dom16_0", "out3/set"), "ON")
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) & 0x0008, 5, "out3 on the device")
        state = self.sub.wait(topic("hub0/dom16_0", "state"), lambda m: m.json()["out3"], mark)
        self.assertEqual(state.json()["word"], before | 0x0008)
        self.rig.wait_log(r"write by mqtt_json to unit 1 \(hub0\): "
                          r"set hub0/dom16_0/out3 = ON: confirmed", since=log)
        self.sub.publish(topic("hub0/dom16_0", "out3/set"), "OFF")
        self.sub.wait(topic("hub0/dom16_0", "state"), lambda m: not m.json()["out3"], mark)
        self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0008, 0)

    def test_other_writable_points(self):
        mark = self.sub.mark()
        self.sub.publish(topic("hub0/rgbdm_0", "colour/set"), "magenta")
        self.sub.wait(topic("hub0/rgbdm_0", "state"), lambda m: m.json()["colour"] == "magenta",
                      mark)
        self.assertEqual(self.rig.ctl("get rgbdm:0"), "5")
        self.sub.publish(topic("hub0/mux8m_0", "pos/set"), "6")
        self.sub.wait(topic("hub0/mux8m_0", "state"), lambda m: m.json()["pos"] == 6, mark)
        self.rig.ctl("set count 42", self.rig.id2_ctl)
        self.sub.wait(topic("press/id2", "state"), lambda m: m.json()["count"] == 42, mark)
        self.sub.publish(topic("press/id2", "reset/set"), "ON")  # Home Assistant's button
        self.sub.wait(topic("press/id2", "state"), lambda m: m.json()["count"] == 0, mark)

    def test_a_set_to_a_silent_module_never_shows_as_set(self):
        mark, log = self.sub.mark(), self.rig.log_mark()
        self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0020, 0)
        self.rig.ctl("fault dom16:0 silent")
        try:
            self.sub.publish(topic("hub0/dom16_0", "out5/set"), "ON")
            self.rig.wait_log(r"set hub0/dom16_0/out5 = ON: (?!confirmed)", since=log)
            self.sub.wait(topic("hub0/dom16_0", "availability"), lambda m: m.payload == "offline",
                          mark)
        finally:
            self.rig.ctl("fault dom16:0 none")
        self.sub.wait(topic("hub0/dom16_0", "availability"), lambda m: m.payload == "online",
                      mark)
        state = json.loads(retained(self.broker.port, topic("hub0/dom16_0", "state"))[
            topic("hub0/dom16_0", "state")])
        self.assertFalse(state["out5"], "the confirmed value, not the command")
        self.assertFalse(any(m.json().get("out5") for m in
                             self.sub.since(mark, topic("hub0/dom16_0", "state"))))
        self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0020, 0)

    def test_a_bad_set_is_refused_and_logged_and_changes_nothing(self):
        log = self.rig.log_mark()
        refused_before = self.rig.state()["mqtt_json"]["sets_refused"]
        before = self.rig.ctl("get dom16:0")
        self.sub.publish(topic("hub0/dom16_0", "out2/set"), "maybe")
        self.rig.wait_log(r"set hub0/dom16_0/out2 = maybe refused: .*'maybe' is not allowed: "
                          r"send ON or OFF", since=log)
        self.sub.publish(topic("hub0/dim16_0", "in2/set"), "ON")
        self.rig.wait_log(r"set hub0/dim16_0/in2 = ON refused: .*an input", since=log)
        self.sub.publish(topic("hub0/dom16_9", "out2/set"), "ON")
        self.rig.wait_log(r"set hub0/dom16_9/out2 = ON refused: no such link and module", since=log)
        # a second bad payload to dom16_0 within the minute is counted, not logged; to another
        # module it is logged, escaped
        self.sub.publish(topic("hub0/rgbdm_0", "colour/set"), "\x1b[2J\nforged line")
        self.rig.wait_log(r"set hub0/rgbdm_0/colour = \\x1B\[2J\\nforged line refused", since=log)
        eventually(lambda: self.rig.state()["mqtt_json"]["sets_refused"] >= refused_before + 4, 5,
                   "four refusals counted")
        self.assertIn('ioportd_mqtt_json_sets_total{result="refused"}', self.rig.metrics())
        self.assertEqual(self.rig.ctl("get dom16:0"), before)
        self.assertNotIn("write by mqtt_json to unit 1 (hub0): set hub0/dom16_0/out2",
                         self.rig.log_text()[log:])


class OwnDaemon(JsonCase):
    """A daemon of its own for each test."""

    def setUp(self):
        self.rig = None

    def tearDown(self):
        if self.rig:
            self.rig.close()
            self.rig = None

    def start(self, **kwargs):
        self.rig = self.new_rig(**kwargs)
        mark = self.sub.mark()
        self.rig.start_daemon()
        self.wait_online(self.rig, mark)

    def test_read_only_refuses_sets(self):
        self.start(modbus_extra="  read_only: true\n")
        log = self.rig.log_mark()
        before = self.rig.ctl("get dom16:0")
        self.sub.publish(topic("hub0/dom16_0", "out1/set"), "ON")
        self.rig.wait_log(r"set hub0/dom16_0/out1 = ON refused: modbus\.read_only is set", since=log)
        self.assertEqual(self.rig.ctl("get dom16:0"), before)

    def test_a_retained_set_left_on_the_broker_does_not_act_at_connect(self):
        # A broker hands a retained message to a new subscription with the retain flag set
        # (a live one arrives without it, and acts as any set does).
        set_topic = topic("hub0/dom16_0", "out1/set")
        self.sub.publish(set_topic, "ON", retain=True)
        try:
            self.start()
            self.rig.wait_log(r"set hub0/dom16_0/out1 = ON refused: it is a retained message")
            self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0002, 0)
        finally:
            self.sub.publish(set_topic, "", retain=True)  # cleared

    def test_the_will_says_offline_when_the_daemon_is_killed(self):
        self.start()
        mark = self.sub.mark()
        self.rig.daemon.send_signal(signal.SIGKILL)
        self.rig.daemon.wait(5)
        offline = self.sub.wait(f"{PREFIX}/status", lambda m: m.payload == "offline", mark)
        self.assertIsNotNone(offline)
        self.assertEqual(retained(self.broker.port, f"{PREFIX}/status")[f"{PREFIX}/status"],
                         "offline")

    def test_a_clean_stop_says_offline_itself(self):
        self.start()
        mark = self.sub.mark()
        _, code = self.rig.stop_daemon()
        self.assertEqual(code, 0)
        self.sub.wait(f"{PREFIX}/status", lambda m: m.payload == "offline", mark)

    def test_a_removed_module_has_its_configs_cleared_at_reload_and_at_start(self):
        self.start()
        colour = f"{HA}/select/{NODE}/hub0_rgbdm_0_colour/config"
        pos = f"{HA}/number/{NODE}/hub0_mux8m_0_pos/config"
        self.assertIn(colour, retained(self.broker.port, f"{HA}/#"))
        # SIGHUP without the rgbdm: its config goes at once
        self.rig.configure("dim16:0,dom16:0,acm3p:0,mux8m:0")
        text = self.rig.reload(read(self.rig.config))
        self.assertIn("MQTT JSON unchanged", text)
        self.rig.wait_log(r"MQTT JSON: 1 discovery config\(s\) cleared")
        configs = retained(self.broker.port, f"{HA}/#")
        self.assertNotIn(colour, configs)
        self.assertIn(pos, configs)
        # stopped, then started without the mux8m: the configs it left are cleared at start
        self.rig.stop_daemon()
        self.rig.configure("dim16:0,dom16:0,acm3p:0")
        mark = self.sub.mark()
        self.rig.start_daemon()
        self.wait_online(self.rig, mark)
        self.rig.wait_log(r"discovery config homeassistant/number/ioportd_box7/"
                          r"hub0_mux8m_0_(pos|neg)/config cleared")
        eventually(lambda: pos not in retained(self.broker.port, f"{HA}/#"), 5,
                   "the mux8m's configs cleared")
        self.assertIn(f"{HA}/switch/{NODE}/hub0_dom16_0_out0/config",
                      retained(self.broker.port, f"{HA}/#"))

    def test_a_reload_publishes_bridge_info_again_and_a_link_without_its_port_is_off(self):
        self.start()
        config = read(self.rig.config).replace("mqtt_json:\n", f"""  - name: spare
    protocol: ioport
    device: {self.rig.dir}/no-such-port
    unit_id: 3
    modules:
      - {{ type: dim16, number: 1 }}
mqtt_json:
""")
        mark = self.sub.mark()
        self.assertIn("SIGHUP: reloaded", self.rig.reload(config))
        info = self.sub.wait(f"{PREFIX}/bridge/info", lambda m: [
            link["name"] for link in m.json()["links"]] == ["hub0", "press", "spare"], mark)
        spare = info.json()["links"][2]
        self.assertEqual((spare["protocol"], spare["unit_id"], spare["modules"][0]["id"]),
                         ("ioport", 3, "dim16_1"))
        self.assertEqual(retained(self.broker.port, f"{PREFIX}/bridge/info")[
            f"{PREFIX}/bridge/info"], info.payload)
        # The new link's connectivity sensor, off: its port is not open.
        self.assertIn(f"{HA}/binary_sensor/{NODE}/spare_connectivity/config",
                      retained(self.broker.port, f"{HA}/binary_sensor/{NODE}/+/config"))
        self.sub.wait(f"{PREFIX}/bridge/connectivity/spare", lambda m: m.payload == "OFF", mark)
        answer = self.ask("health_check", '{"transaction": false}')
        self.assertEqual((answer["status"], answer["transaction"]), ("ok", False))
        self.assertEqual(answer["data"], {"healthy": False, "links": {
            "hub0": "ok", "press": "ok",
            "spare": f"link spare: port {self.rig.dir}/no-such-port not open"}})

    def test_a_retained_request_left_on_the_broker_is_answered_error_at_connect(self):
        request = f"{PREFIX}/bridge/request/health_check"
        self.sub.publish(request, '{"transaction": "left"}', retain=True)
        try:
            mark = self.sub.mark()
            self.start()
            answer = self.sub.wait(f"{PREFIX}/bridge/response/health_check",
                                   lambda m: m.json().get("transaction") == "left", mark)
            self.assertEqual((answer.json()["status"], answer.json()["data"]), ("error", {}))
            self.assertIn("a retained request is not served", answer.json()["error"])
        finally:
            self.sub.publish(request, "", retain=True)  # cleared
        # A live one is served.
        self.sub.publish(request, '{"transaction": "live"}')
        live = self.sub.wait(f"{PREFIX}/bridge/response/health_check",
                             lambda m: m.json().get("transaction") == "live", mark)
        self.assertEqual(live.json()["status"], "ok")

    def test_a_reload_renames_live(self):
        self.start()
        config = read(self.rig.config).replace("supply temperature", "flow temperature")
        mark = self.sub.mark()
        self.rig.reload(config)
        name = f"{HA}/sensor/{NODE}/hub0_acm3p_0_value0/config"
        self.sub.wait(name, lambda m: json.loads(m.payload)["name"] == "flow temperature", mark)

    def test_the_broker_going_away_costs_nothing_and_the_session_comes_back(self):
        self.start()
        self.broker.stop()
        log = self.rig.log_mark()
        self.rig.wait_log(r"mqtt_json: .*reconnecting within", since=log)
        self.rig.ctl("set dim16:0 0x00FF")  # while the broker is away
        self.broker.start()
        self.sub.close()  # its session went with the broker
        type(self).sub = Subscriber(self.broker.port)
        self.rig.wait_log(r"mqtt_json: connected to", 10, since=log)
        # The log says so at the CONNACK; what the new session publishes follows it.
        state = topic("hub0/dim16_0", "state")

        def republished():
            kept = retained(self.broker.port, f"{PREFIX}/#")
            return (kept.get(f"{PREFIX}/status") == "online" and state in kept
                    and json.loads(kept[state])["word"] == 0x00FF)
        eventually(republished, 10, "status online and the state changed meanwhile, retained")


class Bridge(JsonCase):
    """The bridge topics of gateway.md §7.3 (zigbee2mqtt's conventions), on a daemon of the
    class's."""

    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        cls.rig = JsonRig(tempfile.mkdtemp(dir=cls.dir), cls.broker.port)
        cls.rig.start_daemon()

    def setUp(self):
        self.wait_online(self.rig)

    def test_info_is_retained_and_describes_the_gateway(self):
        # Published at connect (the modules not polled yet), then again once their status is
        # known, at most once a second.
        def all_online():
            kept = retained(self.broker.port, f"{PREFIX}/bridge/info")
            info = json.loads(kept.get(f"{PREFIX}/bridge/info", "{}"))
            modules = [m for link in info.get("links", []) for m in link["modules"]]
            return modules and all(m["status"] == "online" for m in modules) and info
        info = eventually(all_online, 10, "bridge/info with every module online")
        self.assertEqual(sorted(info), ["discovery", "links", "read_only", "version"])
        self.assertEqual((info["discovery"], info["read_only"]), (True, False))
        hub, press = info["links"]
        self.assertEqual((hub["name"], hub["protocol"], hub["unit_id"]), ("hub0", "ioport", 1))
        self.assertEqual((press["name"], press["protocol"], press["unit_id"]), ("press", "id2", 2))
        self.assertEqual([m["id"] for m in hub["modules"]],
                         ["dim16_0", "dom16_0", "acm3p_0", "rgbdm_0", "mux8m_0"])
        boiler = hub["modules"][2]
        self.assertEqual((boiler["type"], boiler["name"]), ("acm3p", "boiler 1"))
        self.assertEqual(press["modules"], [{"id": "id2", "type": "id2", "name": "ID-2",
                                             "status": "online"}])
        # The request "info" publishes it again, and answers ok.
        mark = self.sub.mark()
        self.assertEqual(self.ask("info", '{"transaction": 7}'),
                         {"status": "ok", "data": {}, "transaction": 7})
        self.sub.wait(f"{PREFIX}/bridge/info", since=mark)

    def test_health_check_echoes_the_transaction_and_tells_each_link(self):
        answer = self.ask("health_check", '{"transaction": "abc-1"}')
        self.assertEqual(answer, {"status": "ok", "transaction": "abc-1", "data": {
            "healthy": True, "links": {"hub0": "ok", "press": "ok"}}})
        self.rig.ctl("fault dim16:0 silent")
        try:
            eventually(lambda: self.ask("health_check", "{}")["data"]["links"]["hub0"] != "ok",
                       10, "hub0 unhealthy", interval=0.25)  # within the 10 a second
            answer = self.ask("health_check", "{}")
            self.assertFalse(answer["data"]["healthy"])
            self.assertEqual(answer["data"]["links"]["press"], "ok")
            self.assertIn("dim16 0 no answer", answer["data"]["links"]["hub0"])
            self.assertNotIn("transaction", answer)
        finally:
            mark = self.sub.mark()
            self.rig.ctl("fault dim16:0 none")
            # The daemon is the class's: the next test finds the module back and its news out
            # (a test that clears the retained states found hub0's ON retained again after it).
            self.sub.wait(f"{PREFIX}/bridge/connectivity/hub0", lambda m: m.payload == "ON", mark)

    def test_anything_else_is_answered_error_with_the_reason(self):
        for name, payload, error in (
                ("permit_join", '{"transaction": 1}', "'permit_join' is not a request here"),
                ("health_check", "not json", "the payload is"),
                ("health_check", "[1]", "the payload is"),
                ("health_check", '{"transaction": [1]}', "transaction: a string of at most"),
                ("health_check", '{"transaction": "' + "x" * 129 + '"}', "at most 128 bytes")):
            with self.subTest(name=name, payload=payload):
                answer = self.ask(name, payload)
                self.assertEqual((answer["status"], answer["data"]), ("error", {}))
                self.assertIn(error, answer["error"])
        self.assertEqual(self.ask("nope", '{"transaction": "t"}')["transaction"], "t")

    def test_requests_are_rate_limited(self):
        def dropped():
            return int(re.search(r'(?m)^ioportd_mqtt_json_bridge_requests_total'
                                 r'\{result="dropped"\} (\d+)$', self.rig.metrics()).group(1))
        before = dropped()
        mark = self.sub.mark()
        for i in range(30):
            self.sub.client.publish(f"{PREFIX}/bridge/request/health_check",
                                    f'{{"transaction": {i}}}', qos=1)

        def answered():
            return len(self.sub.since(mark, f"{PREFIX}/bridge/response/health_check"))
        eventually(lambda: answered() + dropped() - before == 30, 10,
                   lambda: f"{answered()} answered, {dropped() - before} dropped")
        # 10 a second: what the tests before left of this second, and perhaps the next's.
        self.assertLessEqual(answered(), 20)
        self.assertGreater(dropped() - before, 0)
        self.rig.wait_log(r"bridge request health_check dropped: more than 10 a second")

    def test_connectivity_per_link_on_the_gateways_device(self):
        configs = retained(self.broker.port, f"{HA}/binary_sensor/{NODE}/+/config")
        hub = json.loads(configs[f"{HA}/binary_sensor/{NODE}/hub0_connectivity/config"])
        self.assertEqual((hub["state_topic"], hub["device_class"], hub["device"]["identifiers"]),
                         (f"{PREFIX}/bridge/connectivity/hub0", "connectivity", [NODE]))
        state = f"{PREFIX}/bridge/connectivity/hub0"
        self.assertEqual(retained(self.broker.port, state)[state], "ON")
        mark = self.sub.mark()
        self.rig.ctl("fault mux8m:0 silent")
        try:
            self.sub.wait(state, lambda m: m.payload == "OFF", mark)
        finally:
            self.rig.ctl("fault mux8m:0 none")
        self.sub.wait(state, lambda m: m.payload == "ON", mark)

    def test_home_assistants_birth_publishes_every_state_again(self):
        # A broker without persistence, restarted: what the gateway published is gone (Home
        # Assistant shows "unknown"), the discovery configs aside. The gateway's status too: on
        # an ejabberd cluster, whose retained messages stay on their node, a Home Assistant on
        # the other node never had it, and every entity stayed unavailable (issue 49).
        modules = ("hub0/dim16_0", "hub0/dom16_0", "hub0/acm3p_0", "hub0/rgbdm_0",
                   "hub0/mux8m_0", "press/id2")
        topics = [topic(m, leaf) for m in modules for leaf in ("state", "availability")] + [
            f"{PREFIX}/bridge/connectivity/{link}" for link in ("hub0", "press")] + [
            f"{PREFIX}/status"]
        for name in topics:
            self.sub.publish(name, "", retain=True)
        eventually(lambda: not set(topics) & set(retained(self.broker.port, f"{PREFIX}/#")), 5,
                   lambda: "the states cleared from the broker; still retained: " + repr(
                       set(topics) & set(retained(self.broker.port, f"{PREFIX}/#"))))
        mark = self.sub.mark()
        self.sub.publish(f"{HA}/status", "online")

        def back():
            kept = retained(self.broker.port, f"{PREFIX}/#")
            return set(topics) <= set(kept) and kept
        kept = eventually(back, 10, lambda: "every state, availability and connectivity "
                          "retained again; missing: " + repr(
                              set(topics) - set(retained(self.broker.port, f"{PREFIX}/#"))))
        for module in modules:
            self.assertEqual(kept[topic(module, "availability")], "online", module)
            self.assertEqual(sorted(json.loads(kept[topic(module, "state")])),
                             sorted(json.loads(self.sub.since(0, topic(module, "state"))[0]
                                               .payload)), module)
        self.assertEqual([kept[f"{PREFIX}/bridge/connectivity/{link}"]
                          for link in ("hub0", "press")], ["ON", "ON"])
        self.assertEqual(kept[f"{PREFIX}/status"], "online")
        # The broker retains a message before it delivers it to this subscriber.
        eventually(lambda: self.sub.since(mark, topic("hub0/dim16_0", "availability")), 5,
                   "hub0/dim16_0's availability published again, not only retained")


class TakingOverBroker(ScriptedBroker):
    """Answers an MQTT 5 CONNECT with CONNACK, then at once DISCONNECT with reason code 0x8E
    (Session taken over), as MQTT 5 brokers do when another client connects with the same
    client id, and reads until the client closes."""

    def serve(self, conn):
        with conn:
            try:
                read_packet(conn)
                conn.sendall(bytes([0x20, 3, 0, 0, 0]))  # CONNACK: no session, success, no property
                conn.sendall(bytes([0xE0, 2, 0x8E, 0]))  # DISCONNECT: Session taken over
                while read_packet(conn)[0] is not None:
                    pass
            except (OSError, IndexError):
                pass


class FromOutside(unittest.TestCase):
    """Issue 37: what a neighbour on the broker can send. A broker of the class's own, without
    the Subscriber of every topic the other classes have (it would take the huge message too)."""

    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="ioportd-json-hostile-")
        cls.broker = Broker(cls.dir)
        cls.broker.start()

    @classmethod
    def tearDownClass(cls):
        cls.broker.stop()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def setUp(self):
        self.rig = JsonRig(tempfile.mkdtemp(dir=self.dir), self.broker.port)
        self.limit = MemoryLimit(256 << 20)  # the unit's MemoryMax=

    def tearDown(self):
        self.rig.close()
        self.limit.close()

    def test_a_huge_set_never_reaches_the_daemon(self):
        # Before: libmosquitto read a 250 MB set whole, and the daemon was OOM-killed under the
        # unit's MemoryMax=256M. Now the CONNECT says 64 KiB at most, and Mosquitto keeps it.
        self.huge_set("5")
        self.assertRegex(self.rig.metrics(),
                         r'(?m)^ioportd_mqtt_json_sets_total\{result="refused"\} 0$')

    def test_a_huge_set_in_mqtt_3_1_1_is_refused_unread(self):
        # MQTT 3.1.1 cannot ask for a bound: Mosquitto sends the 250 MB, and the relay under
        # libmosquitto reads it in passing (gateway.md §7.5). Before, the same RSS as ever.
        self.huge_set("3.1.1")
        self.assertRegex(self.rig.metrics(),
                         r'(?m)^ioportd_mqtt_json_sets_total\{result="refused"\} 1$')
        self.rig.wait_log(r"MQTT JSON: set hub0/dom16_0/out3 refused unread: 2621440\d\d bytes, "
                          r"more than the 65536 a message to this gateway may have")

    def huge_set(self, protocol):
        self.rig.configure(HUB, f'  protocol: "{protocol}"\n')
        self.rig.start_daemon()
        self.rig.wait_log(r"mqtt_json: connected to \S+ as ioportd-json_ioportd_2Fbox7 "
                          rf"\(MQTT {re.escape(protocol)}\)")
        pid = self.rig.daemon.pid
        self.limit.add(pid)
        sub = Subscriber(self.broker.port, (f"{PREFIX}/status",), client_id="hostile-watch")
        sub.wait(f"{PREFIX}/status", lambda m: m.payload == "online")
        rss = peak_rss(pid)
        attacker = RawClient(self.broker.port, "hostile", 10 * SLOWDOWN)
        attacker.publish(topic("hub0/dom16_0", "out3/set"), b"1" * (250 << 20), 60 * SLOWDOWN)
        sub.close()

        # The small set after it acts; the huge one never came. Mosquitto reads a PUBLISH whole
        # before it serves anyone else: on a loaded machine the 250 MB can hold it past the
        # daemon's keepalive (5 s here), the daemon reconnects, and a set sent before it has
        # subscribed again is gone with its clean session. So the set is sent until it acts.
        def out4_set():
            attacker.publish(topic("hub0/dom16_0", "out4/set"), b"ON", 10 * SLOWDOWN)
            return int(self.rig.ctl("get dom16:0"), 0) & 0x0010
        eventually(out4_set, 20, lambda: f"out4 on; ioportd's log:\n{self.rig.log_text()[-3000:]}",
                   interval=0.5)
        attacker.close()
        self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0008, 0)
        self.assertIsNone(self.rig.daemon.poll(), "ioportd is running")
        grown = peak_rss(pid) - rss
        print(f"\na 250 MB set: peak RSS {grown / 1048576:+.1f} MiB", file=sys.stderr)
        if RSS_TELLS:
            self.assertLess(grown, 32 << 20)
        self.assertRegex(self.rig.metrics(),
                         r'(?m)^ioportd_mqtt_json_sets_total\{result="accepted"\} [1-9]')

    def test_a_burst_of_home_assistant_births_republishes_once(self):
        # Before: every birth a second after the last republication republished every config
        # and state: 295 births in 6 s made 710 messages of 207 kB (five modules). Now the first
        # is served at once, the rest by one republication when 30 s have passed
        # (gateway.md §7.5; BirthPacer's unit tests wait the 30 s on a clock of their own).
        self.rig.start_daemon()
        sub = Subscriber(self.broker.port, (f"{HA}/+/{NODE}/+/config", f"{PREFIX}/#"),
                         client_id="birth-watch")
        attacker = RawClient(self.broker.port, "hostile", 10 * SLOWDOWN)
        try:
            sub.wait(f"{PREFIX}/status", lambda m: m.payload == "online")
            # Its configs follow its status: on a loaded machine some are still on their way.
            def retained_configs():
                found = set(retained(self.broker.port, f"{HA}/+/{NODE}/+/config"))
                return found if len(found) > 40 else None
            configs = eventually(retained_configs, 20, "more than 40 discovery configs retained",
                                 interval=0.2)
            mark = sub.mark()
            births, end = 0, time.monotonic() + 6
            while time.monotonic() < end:
                attacker.publish(f"{HA}/status", b"online", 10 * SLOWDOWN)
                births += 1
            # A request after the births: its answer comes after whatever they made.
            attacker.publish(f"{PREFIX}/bridge/request/health_check", b"{}", 10 * SLOWDOWN)
            sub.wait(f"{PREFIX}/bridge/response/health_check", since=mark, timeout=20)
            made = [m for m in sub.since(mark) if not m.retain and "/bridge/response/" not in
                    m.topic]
            size = sum(len(m.topic) + len(m.payload.encode()) for m in made)
            print(f"\n{births} Home Assistant births in 6 s: {len(made)} messages, "
                  f"{size / 1000:.1f} kB", file=sys.stderr)
            sent = [m.topic for m in made if m.topic.endswith("/config")]
            self.assertEqual(sorted(sent), sorted(configs), "every config once, no more")
            # A republication sends each state, availability and connectivity as it is, the same
            # as the last message on its topic; a module that timed out under load meanwhile
            # sends changes (offline, then online), which are not republications, and so does
            # bridge/info, which says the modules' status (once offline and online again, the
            # same text as before: it is not counted).
            repeats, last = {}, {}
            for m in made:
                if re.search(r"/(state|availability|connectivity/[^/]+|status)$", m.topic):
                    if last.get(m.topic, m.payload) == m.payload:
                        repeats[m.topic] = repeats.get(m.topic, 0) + 1
                    last[m.topic] = m.payload
            self.assertEqual(set(repeats.values()), {1},
                             "every state and availability once, no more: "
                             + str([(m.topic, m.payload) for m in made if "/config" not in m.topic]))
            self.assertIsNone(self.rig.daemon.poll(), "ioportd is running")
            self.rig.wait_log(r"MQTT JSON: Home Assistant's birth on homeassistant/status served "
                              r"at most once every 30 s; the next republication when they are "
                              r"over \(logged once a minute\)")
        finally:
            attacker.close()
            sub.close()

    def test_hostile_bridge_requests_are_answered_in_a_few_bytes_and_the_daemon_lives(self):
        # Before: a number beyond a double's range anywhere in a request made the JSON parser
        # throw what nobody caught, and the daemon ended; an unterminated 60 KB string came back
        # whole in the error, as the parser quoted it.
        self.rig.start_daemon()
        sub = Subscriber(self.broker.port, (f"{PREFIX}/status", f"{PREFIX}/bridge/response/#"),
                         client_id="hostile-watch")
        try:
            sub.wait(f"{PREFIX}/status", lambda m: m.payload == "online")
            for name, payload, error in (
                    ("health_check", '{"transaction": 1e400}', "number overflow"),
                    ("health_check", '{"x": [-1e999], "transaction": "t"}', "number overflow"),
                    ("health_check", '{"transaction": "' + "x" * 60000, "missing closing quote"),
                    ("health_check", '{"transaction": 1' + "0" * 60000 + "}", "number overflow"),
                    ("info", '{"transaction": "\\u0000\\u001b[2J"}', None),
                    ("n" * 300, '{"transaction": 1}', "is not a request here")):
                with self.subTest(name=name[:20], payload=payload[:40]):
                    mark = sub.mark()
                    sub.publish(f"{PREFIX}/bridge/request/{name}", payload)
                    answer = sub.wait(f"{PREFIX}/bridge/response/{name}", since=mark)
                    self.assertLess(len(answer.payload), 512)
                    if error:
                        self.assertEqual(answer.json()["status"], "error")
                        self.assertIn(error, answer.json()["error"])
                    else:
                        self.assertEqual(answer.json(), {"status": "ok", "data": {},
                                                         "transaction": "\u0000\u001b[2J"})
            self.assertIsNone(self.rig.daemon.poll(), "ioportd is running")
            mark = sub.mark()
            sub.publish(f"{PREFIX}/bridge/request/health_check", '{"transaction": 2}')
            self.assertEqual(sub.wait(f"{PREFIX}/bridge/response/health_check",
                                      since=mark).json()["transaction"], 2)
        finally:
            sub.close()

    def start_daemon_on(self, broker):
        """The daemon, on a ScriptedBroker (started here, closed after the test)."""
        broker.start()
        self.addCleanup(broker.close)
        self.rig.broker_port = broker.port
        self.rig.configure(HUB)
        self.rig.start_daemon()

    def falls_back_to_3_1_1(self, old, how):
        """The daemon on `old`, which does not take MQTT 5: it says `how` (a pattern) the broker
        answered, then speaks 3.1.1 with it."""
        self.start_daemon_on(old)
        self.rig.wait_log(rf"mqtt_json: mqtt://127\.0\.0\.1:{old.port} {how}, so MQTT 3\.1\.1 "
                          r"with it from now on; a message larger than 65536 bytes is read in "
                          r"passing and refused", 10)
        self.rig.wait_log(r"mqtt_json: connected to \S+ as \S+ \(MQTT 3\.1\.1\)", 10)
        self.assertEqual(old.levels[:2], [5, 4])

    def test_a_broker_without_mqtt5_is_spoken_to_in_3_1_1(self):
        self.falls_back_to_3_1_1(Mqtt311Broker(), "refused MQTT 5")

    def test_a_broker_that_closes_on_mqtt5_is_spoken_to_in_3_1_1(self):
        # RabbitMQ 3.10 closes the connection on an MQTT 5 CONNECT, without a CONNACK. Before,
        # the daemon tried 5 again and again and never connected (issue 49).
        self.falls_back_to_3_1_1(Mqtt311Broker(silent=True), "closed the connection after an MQTT "
                                 "5 CONNECT, without a CONNACK")

    def test_protocol_5_keeps_to_5(self):
        old = Mqtt311Broker()
        old.start()
        self.addCleanup(old.close)
        self.rig.broker_port = old.port
        self.rig.configure(HUB, '  protocol: "5"\n')
        self.rig.start_daemon()
        self.rig.wait_log(rf"mqtt_json: mqtt://127\.0\.0\.1:{old.port} refused MQTT 5; "
                          r'protocol: "5" is set, so no MQTT 3\.1\.1: set protocol: auto', 10)
        self.assertNotIn(4, old.levels)

    def test_a_disconnect_from_the_broker_is_logged_with_its_reason(self):
        # Before: "connection ... lost: Unknown error." (the reason code given to strerror).
        rival = TakingOverBroker()
        self.start_daemon_on(rival)
        self.rig.wait_log(rf"mqtt_json: mqtt://127\.0\.0\.1:{rival.port} sent DISCONNECT: "
                          r"Session taken over \(reason code 0x8E\); another client connected "
                          r"as ioportd-json_ioportd_2Fbox7: give each its own client_id; "
                          r"reconnecting within 1 s", 10)


@unittest.skipUnless(NODE_RED_DIR, "Node-RED is not installed (tests/mqtt_json/node_red.py)")
class NodeRed(JsonCase):
    """A real consumer, one Node-RED for the class with two flows: one subscribes to dim16_0's
    state and, when in0 is on, sets dom16_0's out7 (an interlock a plant would wire the same way);
    the other asks bridge/request/health_check with a transaction and takes the answer that
    echoes it (gateway.md §7.3), as a flow made for zigbee2mqtt does."""

    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        cls.red = None
        try:
            cls.rig = JsonRig(tempfile.mkdtemp(dir=cls.dir), cls.broker.port)
            cls.rig.ctl("set dim16:0 0x0000")
            cls.rig.start_daemon()
            cls.sub.wait(f"{PREFIX}/status", lambda m: m.payload == "online", timeout=20)
            cls.red = node_red.NodeRed(NODE_RED_DIR, cls.dir, cls.broker.port,
                                       topic("hub0/dim16_0", "state"),
                                       topic("hub0/dom16_0", "out7/set"), f"{PREFIX}/bridge")
            cls.red.__enter__()
        except BaseException:
            cls.tearDownClass()
            raise

    @classmethod
    def tearDownClass(cls):
        if cls.red:
            cls.red.__exit__()
        super().tearDownClass()

    def setUp(self):
        self.wait_online(self.rig)

    def test_a_flow_reads_a_state_and_sets_an_output(self):
        mark = self.sub.mark()
        self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0080, 0)
        self.rig.ctl("set dim16:0 0x0001")
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) & 0x0080, 20, "Node-RED set out7")
        self.sub.wait(topic("hub0/dom16_0", "state"), lambda m: m.json()["out7"], mark)
        self.rig.wait_log(r"write by mqtt_json to unit 1 \(hub0\): set hub0/dom16_0/out7 = "
                          r"ON: confirmed")

    def test_a_flow_asks_health_check_with_a_transaction_and_gets_its_answer(self):
        transaction = f"node-red-{time.monotonic_ns()}"
        request = f"{PREFIX}/bridge/request/health_check"
        response = f"{PREFIX}/bridge/response/health_check"
        mark = self.sub.mark()
        # Node-RED drops what its mqtt out nodes get before its connection is up, and the ask
        # topic's subscription may follow "Connected to broker": asked again every second until
        # the answer is there.
        asked = [time.monotonic() - 1]

        def answered():
            if time.monotonic() - asked[-1] >= 1:
                self.sub.publish(node_red.ASK, transaction)
                asked.append(time.monotonic())
            relayed = self.sub.since(mark, node_red.ANSWER)
            return relayed[0] if relayed else None
        relayed = eventually(answered, 30, lambda: "Node-RED's answer:\n" + repr(
            [(m.topic, m.payload) for m in self.sub.since(mark)][-10:]) + "\n" +
            self.red.log_text()[-3000:], interval=0.05)
        self.assertEqual(relayed.json(), {"answer": {
            "status": "ok", "transaction": transaction,
            "data": {"healthy": True, "links": {"hub0": "ok", "press": "ok"}}}})
        # What went over the broker: Node-RED's request (the test never publishes one), the
        # gateway's answer, not retained.
        self.assertIn({"transaction": transaction},
                      [m.json() for m in self.sub.since(mark, request)])
        answer = self.sub.wait(response, lambda m: m.json().get("transaction") == transaction,
                               mark)
        self.assertFalse(answer.retain)
        self.assertLess(answer.index, relayed.index)


def read(path):
    with open(path) as f:
        return f.read()


if __name__ == "__main__":
    if NODE_RED_DIR:
        node_red.install(NODE_RED_DIR)
    unittest.main(argv=sys.argv[:1] + sys.argv[4:], verbosity=2)
