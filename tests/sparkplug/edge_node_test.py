#!/usr/bin/python3
"""ioportd as a Sparkplug B 3.0 edge node (gateway.md §5.5, issue 17), end to end: a real
mosquitto broker on a free loopback port, the real simulators on ptys, the real daemon, and the
host application of host_app.py, which checks the specification's rules on every message of every
test (each test ends by asserting it recorded no violation), and BrokerLog, which checks what
only the broker sees (CONNECT, will, SUBSCRIBE, QoS and retain) in mosquitto's log. Each test names
the Sparkplug 3.0 TCK ids it checks (@covers); docs/sparkplug-conformance.md lists them all.

Usage: edge_node_test.py IOPORTD IOPORT_SIM PYTHON_DIR   (PYTHON_DIR holds sparkplug_b_pb2.py)
"""
import json
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import unittest

IOPORTD, IOPORT_SIM, PYTHON_DIR = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.insert(0, PYTHON_DIR)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))

from pymodbus.client import ModbusTcpClient  # noqa: E402
from pymodbus.exceptions import ModbusIOException  # noqa: E402

import sparkplug_b_pb2 as pb  # noqa: E402
from host_app import BrokerLog, HostApp, encode_value  # noqa: E402
from tck import covers  # noqa: E402
from broker import Broker  # noqa: E402
from process_memory import RSS_TELLS, MemoryLimit, cpu_seconds, peak_rss  # noqa: E402
from raw_mqtt import Mqtt311Front, RawClient, SubackHoldingFront  # noqa: E402
from rig import SLOWDOWN, Rig, eventually, free_port  # noqa: E402

GROUP, NODE = "plant1", "box7"
CLIENT_ID = f"ioportd-{GROUP}-{NODE}"
HUB_MODULES = ["dim16:0", "dom16:0", "acm3p:0", "rgbdm:0"]


def bits(prefix):
    return [(f"{prefix}/{k}", "Boolean") for k in range(16)] + [("word", "UInt16")]


# Every module's metrics as gateway.md §5.5 lists them (sparkplug::module_metrics), in order.
METRICS = {
    "hub0.dim16.0": bits("in"),
    "hub0.dom16.0": bits("out"),
    "hub0.acm3p.0": [(f"raw/{c}", "UInt16") for c in range(3)] +
                    [(f"value/{c}", "Float") for c in range(3)],
    "hub0.rgbdm.0": [("colour", "UInt8")],
    "hub0.mux8m.0": [("pos", "UInt8"), ("neg", "UInt8")],
    "press.id2": [("stop", "Boolean"), ("count", "UInt16"), ("reset", "Boolean")],
}
TYPE_NUMBERS = {"Int64": 4, "UInt8": 5, "UInt16": 6, "UInt64": 8, "Float": 9, "Boolean": 11}


class EdgeNodeRig(Rig):
    """ioport-sim with a hub and one with an ID-2, and ioportd on them as edge node plant1/box7,
    in a temporary directory."""

    def __init__(self, directory, broker_port, hub_modules=HUB_MODULES, mqtt_extra="",
                 broker_url=None, modbus_extra="", hub_extra="", broker_ports=None):
        super().__init__(directory, IOPORTD, IOPORT_SIM)
        self.broker_url = broker_url or f"mqtt://127.0.0.1:{broker_port}"
        # Several brokers (gateway.md §6.2): `brokers:` instead of `broker:`.
        self.broker_urls = [f"mqtt://127.0.0.1:{p}" for p in broker_ports or []]
        try:
            self.start_hub("dim16:0,dom16:0,acm3p:0,rgbdm:0,mux8m:0")
            self.start_id2()
        except BaseException:
            self.close()
            raise
        self.configure(hub_modules, mqtt_extra, modbus_extra, hub_extra)

    def configure(self, hub_modules, mqtt_extra="", modbus_extra="", hub_extra="",
                  module_extra=None):
        """Writes the configuration: these modules of the hub, and lines to add under mqtt:,
        modbus: and the link hub0; `module_extra` adds keys to modules ("acm3p:0" -> ", name:
        x")."""
        extra = module_extra or {}
        modules = "\n".join(f"      - {{ type: {m.split(':')[0]}, number: {m.split(':')[1]}"
                            f"{extra.get(m, '')} }}" for m in hub_modules)
        brokers = (f"brokers: {json.dumps(self.broker_urls)}" if self.broker_urls
                   else f'broker: "{self.broker_url}"')
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
{hub_extra}    modules:
{modules}
  - name: press
    protocol: id2
    device: {self.id2_link}
    unit_id: 2
mqtt:
  {brokers}
  group_id: {GROUP}
  edge_node_id: {NODE}
  keepalive: 5s
{mqtt_extra}""")

    def start_daemon(self):
        super().start_daemon()
        self.port = self.listening_port("Modbus TCP")

    def id2(self, command):
        return self.ctl(command, self.id2_ctl)


class SparkplugCase(unittest.TestCase):
    """A broker and a host app for the class; checks the host app's rules after every test.

    The broker keeps the host app's session over a restart: the node, reconnecting on its own
    timer, may come back before the host app does, and what it sends then (births, forwarded
    history) waits at the broker for the host app instead of being lost to it."""
    mqtt_extra = ""

    def assertModbusAnswers(self, client):
        """Modbus answers: a value, or an exception (a module briefly offline on a busy machine
        answers one); no answer at all (pymodbus's ModbusIOException) is what fails."""
        self.assertNotIsInstance(client.read_input_registers(0, 1, slave=1), ModbusIOException,
                                 "Modbus did not answer")

    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="ioportd-spb-")
        cls.broker = Broker(cls.dir, keep_sessions=True)
        cls.broker.start()
        cls.host = HostApp(cls.broker.port, keep_session=True)
        cls.broker_log = BrokerLog(cls.broker.log, CLIENT_ID, GROUP, NODE)
        cls.rig = None

    @classmethod
    def tearDownClass(cls):
        if cls.rig:
            cls.rig.close()
        cls.host.close()
        cls.broker.stop()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def tearDown(self):
        violations, self.host.violations[:] = list(self.host.violations), []
        violations += self.broker_log.check()
        self.assertEqual(violations, [], "Sparkplug rules broken")

    def new_rig(self, **kwargs):
        directory = tempfile.mkdtemp(dir=self.dir)
        rig = EdgeNodeRig(directory, self.broker.port, **kwargs)
        return rig

    def modbus(self, rig):
        client = ModbusTcpClient("127.0.0.1", port=rig.port, timeout=3)
        assert client.connect()
        return client

    def value(self, device, name):
        return self.host.value(GROUP, NODE, device, name)

    def wait_births(self, since, devices=tuple(d for d in METRICS if d != "hub0.mux8m.0")):
        nbirth = self.host.wait_message("NBIRTH", since=since, node=NODE, timeout=10)
        for device in devices:
            self.host.wait_message("DBIRTH", device, since=nbirth.index, timeout=10)
        return nbirth

    def rebirths(self, mark, until=None):
        """The DBIRTHs since `mark` (before message `until`) that no DDEATH of their device (a
        module that went offline for a moment on a loaded machine, say) explains."""
        dead, found = set(), []
        for m in self.host.since(mark)[:None if until is None else until - mark]:
            if m.type == "DDEATH":
                dead.add(m.device)
            elif m.type == "DBIRTH" and m.device in dead:
                dead.discard(m.device)
            elif m.type == "DBIRTH":
                found.append(m)
        return found

    def barrier(self, rig, instance=""):
        """Everything the node published about inputs set before this call has arrived: two
        changes of acm3p:0 channel 2 in a row, each waited for in DDATA. Between the polls of
        the acm3p that saw them, the round robin polled every other module once, after the
        caller's change; the node publishes in order and the broker keeps it. The changes are
        of 2.9 %, beyond any deadband of the tests. `instance`: "acm3p/" with templates."""
        for _ in range(2):
            raws = rig.ctl("get acm3p:0").split()
            raws[2] = "2000" if raws[2] == "100" else "100"
            mark = self.host.mark()
            rig.ctl("set acm3p:0 " + " ".join(raws))
            self.host.wait_metric("hub0.acm3p.0", instance + "raw/2", int(raws[2]), since=mark)


class EdgeNode(SparkplugCase):
    """One daemon for the class (deadband 1.0 %), tests in any order."""

    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        cls.rig = EdgeNodeRig(tempfile.mkdtemp(dir=cls.dir), cls.broker.port,
                              mqtt_extra="  deadband: 1.0\n")
        cls.rig.ctl("set dim16:0 0x0005")
        cls.rig.ctl("set acm3p:0 1000 2000 100")
        cls.rig.id2("set count 7")
        mark = cls.host.mark()
        cls.rig.start_daemon()
        cls.births = mark

    def setUp(self):
        self.wait_births(self.births)

    @covers("tck-id-operational-behavior-data-commands-rebirth-datatype",
            "tck-id-operational-behavior-data-commands-rebirth-value",
            "tck-id-operational-behavior-data-commands-rebirth-name-aliases",
            "tck-id-message-flow-edge-node-birth-publish-nbirth-payload-bdSeq",
            "tck-id-operational-behavior-data-publish-nbirth-values",
            "tck-id-operational-behavior-data-publish-dbirth-values",
            "tck-id-payloads-metric-datatype-value")
    def test_births_announce_every_metric_with_current_values(self):
        nbirth = self.host.wait_message("NBIRTH", since=self.births)
        self.assertEqual(nbirth.seq, 0)
        names = {m.name: m for m in nbirth.metrics}
        self.assertEqual(names["bdSeq"].datatype, TYPE_NUMBERS["Int64"])
        self.assertEqual(names["bdSeq"].value, 0)  # the first CONNECT of this daemon
        self.assertEqual(names["Node Control/Rebirth"].datatype, TYPE_NUMBERS["Boolean"])
        self.assertIs(names["Node Control/Rebirth"].value, False)
        # tck-id-operational-behavior-data-commands-rebirth-name-aliases: no alias for Rebirth
        self.assertIsNone(names["Node Control/Rebirth"].alias)
        self.assertEqual(names["Node Control/Next Server"].datatype, TYPE_NUMBERS["Boolean"])
        self.assertIs(names["Node Control/Next Server"].value, False)
        for link in ("hub0", "press"):
            self.assertIs(names[f"link/{link}/up"].value, True)
            for counter in ("transactions_ok", "transactions_failed", "reopens"):
                self.assertEqual(names[f"link/{link}/{counter}"].datatype, TYPE_NUMBERS["UInt64"])
        for device, metrics in METRICS.items():
            if device == "hub0.mux8m.0":
                self.assertEqual(self.host.since(self.births, "DBIRTH", device), [],
                                 "mux8m:0 is not configured")
                continue
            later = self.host.since(nbirth.index + 1, "NBIRTH")  # test_ncmd_rebirth's
            births = [m for m in self.rebirths(nbirth.index + 1, later[0].index if later else None)
                      if m.device == device]
            self.assertEqual(len(births), 1, device)
            got = [(m.name, m.datatype) for m in births[0].metrics]
            self.assertEqual(got, [(n, TYPE_NUMBERS[t]) for n, t in metrics], device)
            self.assertTrue(all(m.alias is not None for m in births[0].metrics))
        # the values of the first births (the simulators were set before the daemon started)
        dim = self.host.since(self.births, "DBIRTH", "hub0.dim16.0")[0].resolved
        self.assertEqual(dim["word"], 5)
        self.assertEqual([dim[f"in/{k}"] for k in range(4)], [True, False, True, False])
        acm = self.host.since(self.births, "DBIRTH", "hub0.acm3p.0")[0].resolved
        self.assertEqual(acm["raw/0"], 1000)
        self.assertAlmostEqual(acm["value/0"], 1000 / 65535 * 100, places=4)
        id2 = self.host.since(self.births, "DBIRTH", "press.id2")[0].resolved
        self.assertEqual((id2["count"], id2["reset"]), (7, False))

    def test_the_broker_log_is_read(self):
        """BrokerLog's rules (checked after every test) ran on the node's own packets."""
        self.assertEqual(self.broker_log.check(), [])
        self.assertGreaterEqual(self.broker_log.connects, 1)
        self.assertGreater(self.broker_log.publishes, 0)
        self.assertEqual(self.broker_log.filters.get(f"spBv1.0/{GROUP}/NCMD/{NODE}"), 1)

    @covers("tck-id-topics-ndata-payload")
    def test_ndata_carries_the_link_counters_that_changed(self):
        # Every counter_period (10 s) the counters that moved since the last NBIRTH or NDATA.
        nbirth = self.host.wait_message("NBIRTH", since=self.births, node=NODE)
        ndata = self.host.wait_message(
            "NDATA", since=nbirth.index, node=NODE, timeout=15,
            where=lambda m: "link/hub0/transactions_ok" in m.resolved)
        self.assertGreater(ndata.resolved["link/hub0/transactions_ok"],
                           nbirth.metric("link/hub0/transactions_ok").value)

    def test_the_status_api_shows_the_session(self):
        state = self.rig.state()["sparkplug"]
        self.assertEqual((state["group_id"], state["edge_node_id"]), (GROUP, NODE))
        self.assertEqual(state["broker"], f"mqtt://127.0.0.1:{self.broker.port}")
        self.assertTrue(state["connected"])
        self.assertTrue(state["online"])
        self.assertGreaterEqual(state["births"], 1)
        self.assertGreater(state["published"], 0)
        self.assertEqual(state["dropped"], 0)

    @covers("tck-id-topics-ddata-payload",
            "tck-id-payloads-alias-data-cmd-requirement")
    def test_input_change_is_published_once_with_only_the_changed_metrics(self):
        self.rig.ctl("set dim16:0 0x0005")
        self.barrier(self.rig)
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x0105")  # in/8 on
        ddata = self.host.wait_message("DDATA", "hub0.dim16.0", since=mark)
        self.assertEqual(ddata.resolved, {"in/8": True, "word": 0x0105})
        self.assertTrue(all(m.name is None and m.alias is not None for m in ddata.metrics),
                        "DDATA goes by alias alone")
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x0105")  # the same value again
        self.barrier(self.rig)
        self.assertEqual(self.host.since(mark, "DDATA", "hub0.dim16.0"), [])
        self.rig.ctl("set dim16:0 0x0005")
        self.host.wait_metric("hub0.dim16.0", "in/8", False, since=mark)

    def test_analog_deadband(self):
        # deadband 1.0 (%): a channel's raw/1 and value/1 go out together, only when the value
        # moved more than 1 % from the last published value (gateway.md §5.5, issue 23 item 13)
        self.rig.ctl("set acm3p:0 1000 2000 100")
        self.barrier(self.rig)
        published = (self.value("hub0.acm3p.0", "raw/1"), self.value("hub0.acm3p.0", "value/1"))
        mark = self.host.mark()
        for noisy in (2030, 1980, 2400, 2010, 1700, 2300):  # noise within ±0.61 %
            self.rig.ctl(f"set acm3p:0 1000 {noisy} 100")
            self.barrier(self.rig)  # each value polled and, were it published, arrived
        channel_1 = [m.resolved for m in self.host.since(mark, "DDATA", "hub0.acm3p.0")
                     if {"raw/1", "value/1"} & m.resolved.keys()]
        print(f"\n  deadband: DDATA of channel 1 for 6 noisy values: {len(channel_1)}",
              file=sys.stderr)
        self.assertEqual(channel_1, [], "a noisy channel within the deadband published")
        self.assertEqual((self.value("hub0.acm3p.0", "raw/1"),
                          self.value("hub0.acm3p.0", "value/1")), published)
        mark = self.host.mark()
        self.rig.ctl("set acm3p:0 1000 2700 100")  # +1.07 % from the published value
        ddata = self.host.wait_metric("hub0.acm3p.0", "raw/1", 2700, since=mark)
        self.assertIn("value/1", ddata.resolved, "raw and value in one DDATA")
        self.assertAlmostEqual(ddata.resolved["value/1"], 2700 / 65535 * 100, places=4)
        self.rig.ctl("set acm3p:0 1000 2000 100")
        self.host.wait_metric("hub0.acm3p.0", "raw/1", 2000, since=mark)

    def test_modbus_and_sparkplug_agree(self):
        client = self.modbus(self.rig)
        try:
            for word, raws in ((0xA5C3, (123, 40000)), (0x0005, (1000, 2000))):
                mark = self.host.mark()
                self.rig.ctl(f"set dim16:0 {word}")
                self.rig.ctl(f"set acm3p:0 {raws[0]} {raws[1]} 100")
                self.host.wait_metric("hub0.dim16.0", "word", word, since=mark)
                self.host.wait_metric("hub0.acm3p.0", "raw/1", raws[1], since=mark)
                self.rig.id2(f"set count {word & 0xFF}")
                self.host.wait_metric("press.id2", "count", word & 0xFF, since=mark)
                bits = client.read_discrete_inputs(0, 16, slave=1)
                self.assertFalse(bits.isError())
                self.assertEqual(bits.bits[:16],
                                 [self.value("hub0.dim16.0", f"in/{k}") for k in range(16)])
                regs = client.read_input_registers(0, 1, slave=1)
                self.assertEqual(regs.registers[0], self.value("hub0.dim16.0", "word"))
                regs = client.read_input_registers(16, 2, slave=1)
                self.assertEqual(regs.registers,
                                 [self.value("hub0.acm3p.0", f"raw/{c}") for c in range(2)])
                # value/0 is the last published value, within the deadband of the exact one
                regs = client.read_input_registers(200, 2, slave=1)  # float32 percent, big
                percent = struct.unpack(">f", struct.pack(">HH", *regs.registers))[0]
                self.assertLessEqual(abs(percent - self.value("hub0.acm3p.0", "value/0")), 1.0)
                coils = client.read_coils(0, 16, slave=1)
                self.assertEqual(coils.bits[:16],
                                 [self.value("hub0.dom16.0", f"out/{k}") for k in range(16)])
                count = client.read_input_registers(0, 1, slave=2)
                self.assertEqual(count.registers[0], self.value("press.id2", "count"))
        finally:
            client.close()

    @covers("tck-id-operational-behavior-device-ddeath")
    def test_fault_gives_ddeath_and_recovery_a_fresh_dbirth(self):
        mark = self.host.mark()
        self.rig.ctl("fault dim16:0 silent")
        self.host.wait_message("DDEATH", "hub0.dim16.0", since=mark)
        self.rig.ctl("set dim16:0 0x00F0")  # changes while it is silent
        self.barrier(self.rig)
        self.assertEqual(self.host.since(mark, "DDATA", "hub0.dim16.0"), [])
        self.rig.ctl("fault dim16:0 none")
        dbirth = self.host.wait_message("DBIRTH", "hub0.dim16.0", since=mark)
        self.assertEqual(dbirth.resolved["word"], 0x00F0)
        self.assertEqual(len(dbirth.metrics), 17)
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x0005")
        self.host.wait_metric("hub0.dim16.0", "word", 5, since=mark)

    @covers("tck-id-operational-behavior-data-commands-rebirth-action-2",
            "tck-id-operational-behavior-data-commands-rebirth-action-3",
            "tck-id-payloads-dbirth-order")
    def test_ncmd_rebirth_keeps_bdseq(self):
        before = self.host.node(GROUP, NODE).bdseq
        mark = self.host.mark()
        self.host.rebirth(GROUP, NODE)
        nbirth = self.wait_births(mark)
        self.assertEqual(nbirth.seq, 0)
        self.assertEqual(nbirth.metric("bdSeq").value, before)
        self.assertEqual(self.host.since(mark, "NDEATH"), [])
        dbirths = self.host.since(mark, "DBIRTH")
        self.assertEqual(sorted(m.device for m in dbirths),
                         sorted(d for d in METRICS if d != "hub0.mux8m.0"))
        self.assertEqual([m.seq for m in dbirths], list(range(1, len(dbirths) + 1)))

    def dom16(self):
        return int(self.rig.ctl("get dom16:0"))

    def test_dcmd_sets_an_output_confirmed_before_published(self):
        self.assertEqual(self.dom16() & 0x0008, 0)
        mark = self.host.mark()
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"name": "out/3", "value": True}])
        ddata = self.host.wait_metric("hub0.dom16.0", "out/3", True, since=mark)
        self.assertEqual(ddata.resolved["word"] & 0x0008, 0x0008)
        self.assertEqual(self.dom16() & 0x0008, 0x0008)
        self.rig.wait_log(r"DCMD hub0\.dom16\.0/out/3 = true: ")  # the audit notice
        mark = self.host.mark()
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"name": "out/3", "value": False}])
        self.host.wait_metric("hub0.dom16.0", "out/3", False, since=mark)
        self.assertEqual(self.dom16() & 0x0008, 0)

    def test_dcmd_by_alias(self):
        alias = self.host.alias(GROUP, NODE, "hub0.dom16.0", "out/7")
        mark = self.host.mark()
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"alias": alias, "value": True}])
        self.host.wait_metric("hub0.dom16.0", "out/7", True, since=mark)
        self.assertEqual(self.dom16() & 0x0080, 0x0080)
        mark = self.host.mark()
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"alias": alias, "value": False}])
        self.host.wait_metric("hub0.dom16.0", "out/7", False, since=mark)
        self.assertEqual(self.dom16() & 0x0080, 0)

    def test_dcmd_out_of_range_is_refused(self):
        before = self.rig.ctl("get rgbdm:0")
        mark, log = self.host.mark(), self.rig.log_mark()
        self.host.dcmd(GROUP, NODE, "hub0.rgbdm.0", [{"name": "colour", "value": 8}])
        self.rig.wait_log(r"DCMD hub0\.rgbdm\.0/colour = 8 refused", since=log)
        # a value of another type is refused too, never converted (and not logged: one line a
        # minute per device and reason; the valid command after it is the barrier)
        self.host.dcmd(GROUP, NODE, "hub0.rgbdm.0",
                       [{"name": "colour", "value": True, "datatype": "Boolean"}])
        # a valid command after them: its DDATA is the only one
        colour = 5 if before != "5" else 6
        self.host.dcmd(GROUP, NODE, "hub0.rgbdm.0", [{"name": "colour", "value": colour}])
        self.host.wait_metric("hub0.rgbdm.0", "colour", colour, since=mark)
        self.assertEqual([m.resolved for m in self.host.since(mark, "DDATA", "hub0.rgbdm.0")],
                         [{"colour": colour}], "a refused command was applied")
        self.assertIsNone(re.search(r"write by sparkplug .*colour = (8|true)",
                                    self.rig.log_text()[log:]))
        self.assertEqual(self.rig.ctl("get rgbdm:0"), str(colour))

    def test_dcmd_to_a_module_that_does_not_answer(self):
        self.assertFalse(self.value("hub0.dom16.0", "out/5"))
        mark, log = self.host.mark(), self.rig.log_mark()
        self.rig.ctl("fault dom16:0 silent")
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"name": "out/5", "value": True}])
        self.rig.wait_log(r"DCMD hub0\.dom16\.0/out/5 = true: (?!confirmed)", since=log)
        self.host.wait_message("DDEATH", "hub0.dom16.0", since=mark)
        self.rig.ctl("fault dom16:0 none")
        dbirth = self.host.wait_message("DBIRTH", "hub0.dom16.0", since=mark)
        self.assertIs(dbirth.resolved["out/5"], False, "the confirmed value, not the command")
        self.assertEqual(self.dom16() & 0x0020, 0)
        self.assertFalse(any(m.resolved.get("out/5") for m in self.host.since(mark)))

    def test_id2_reset(self):
        mark = self.host.mark()
        self.rig.id2("set count 42")
        self.host.wait_metric("press.id2", "count", 42, since=mark)
        mark = self.host.mark()
        self.host.dcmd(GROUP, NODE, "press.id2", [{"name": "reset", "value": True}])
        self.host.wait_metric("press.id2", "count", 0, since=mark)
        self.assertEqual(self.rig.id2("get count"), "0")
        self.assertNotIn("reset", self.host.since(mark, "DDATA", "press.id2")[0].resolved)


class OwnDaemon(SparkplugCase):
    """A daemon of its own for each test."""

    def setUp(self):
        self.rig = self.new_rig()

    def tearDown(self):
        # A clean end that the next test cannot confuse with its own session: SIGTERM, and
        # the NDEATH waited for when the node was born.
        daemon = self.rig.daemon
        if daemon and daemon.poll() is None:
            mark = self.host.mark()
            self.rig.stop_daemon(signal.SIGTERM)
            state = self.host.node(GROUP, NODE)
            if state and state.born:
                self.host.wait_message("NDEATH", since=mark)
        self.rig.close()
        super().tearDown()

    def start(self):
        mark = self.host.mark()
        self.rig.start_daemon()
        return self.wait_births(mark)


def command_payload(metrics):
    """A Sparkplug B payload of (name, Sparkplug datatype, value) metrics, for the broker's raw
    publish."""
    payload = pb.Payload(timestamp=int(time.time() * 1000))
    for name, datatype, value in metrics:
        m = payload.metrics.add(name=name)
        encode_value(m, datatype, value)
    return payload.SerializeToString()


def dcmd_topic(device):
    return f"spBv1.0/{GROUP}/DCMD/{NODE}/{device}"


class HostileCommands(OwnDaemon):
    """What any client of the broker can send (issue 23): commands too large, floods of them,
    names and values made to forge log lines; and modbus.read_only against DCMD."""

    def flood(self, topic, payload, count):
        """`count` publications of `payload`, at QoS 0 as fast as paho takes them, the last at
        QoS 1 and waited for: the broker has them all."""
        client = self.host._client
        for _ in range(count - 1):
            client.publish(topic, payload, qos=0)
        client.publish(topic, payload, qos=1).wait_for_publish(30)

    def served_after_a_flood(self, mark, device, metrics):
        """A condition for timed_reads(): the device's DDATA since `mark`, sending the DCMD of
        `metrics` now and again each second until then. Mosquitto drops QoS 0 messages for a
        subscriber whose queue is full (max_queued_messages, "Outgoing messages are being
        dropped"): a daemon slowed by the sanitizers or a busy machine may still be reading the
        flood when the command follows it, and the broker's drop is no loss of the daemon's."""
        sent = [float("-inf")]

        def served():
            if self.host.since(mark, "DDATA", device):
                return True
            if time.monotonic() - sent[0] >= 1:
                self.host.dcmd(GROUP, NODE, device, metrics)
                sent[0] = time.monotonic()
            return False
        return served

    def timed_reads(self, client, until, deadline=10):
        """Modbus reads one after the other until until() holds (within `deadline` seconds, times
        SLOWDOWN): the slowest, in seconds."""
        slowest, end = 0.0, time.monotonic() + deadline * SLOWDOWN
        while not until():
            self.assertLess(time.monotonic(), end, "not within the deadline")
            asked = time.monotonic()
            self.assertModbusAnswers(client)
            slowest = max(slowest, time.monotonic() - asked)
        return slowest

    def test_a_dcmd_naming_more_metrics_than_writable_is_refused_whole(self):
        self.start()
        before = int(self.rig.ctl("get dom16:0"))
        client = self.modbus(self.rig)
        try:
            log = self.rig.log_mark()
            refused = r"Sparkplug DCMD to hub0\.dom16\.0 refused: refused whole"
            # 4,000 metrics, 51 KiB: over MQTT 5 the broker drops a command beyond 64 KiB for
            # the node (test_a_huge_command_never_reaches_the_daemon); one within it but beyond
            # a dom16's 18 KiB is refused by its size, unread.
            flood = command_payload([("out/0", "Boolean", True)] * 4_000)
            self.assertLess(len(flood), 60 << 10)
            self.host.publish_raw(dcmd_topic("hub0.dom16.0"), flood)
            reads = iter(range(20))  # at least 20, and on until the refusal is logged
            slowest = self.timed_reads(
                client, lambda: next(reads, None) is None and
                re.search(refused, self.rig.log_text()[log:]))
            line = self.rig.wait_log(refused + r": (\d+) bytes, .*", since=log)
            print(f"\n  DCMD of 4,000 out/0 ({len(flood)} bytes): {line.group(0)!r}; slowest "
                  f"Modbus read meanwhile {slowest * 1000:.1f} ms", file=sys.stderr)
            self.assertLess(slowest, 0.2 * SLOWDOWN, "Modbus waited for the DCMD")
            # one metric more than a dom16 writes (17): refused by count, logged with the first
            # (one line a minute per device and reason)
            self.host.publish_raw(dcmd_topic("hub0.dom16.0"),
                                  command_payload([("out/0", "Boolean", True)] * 18))
            self.host.publish_raw(dcmd_topic("hub0.dom16.0"), flood)
            # a barrier: a valid command after them, confirmed
            mark = self.host.mark()
            self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"name": "out/3", "value": True}])
            self.host.wait_metric("hub0.dom16.0", "out/3", True, since=mark)
            text = self.rig.log_text()[log:]
            self.assertEqual(len(re.findall(refused, text)), 1, text[-3000:])
            self.assertIsNone(re.search(r"DCMD hub0\.dom16\.0/out/0", text), "out/0 was written")
            self.assertEqual(int(self.rig.ctl("get dom16:0")), before | 0x0008)
        finally:
            client.close()

    def test_a_dcmd_that_names_no_device_is_counted_and_said(self):
        # Before (issue 49): RabbitMQ turns hub0.dom16.0 into hub0/dom16/0, and such a DCMD
        # never reached the node's subscription (DCMD/box7/+); nothing said where commands went.
        self.start()
        log = self.rig.log_mark()
        on = command_payload([("out/0", "Boolean", True)])
        self.host.publish_raw(f"spBv1.0/{GROUP}/DCMD/{NODE}/hub0/dom16/0", on)
        self.host.publish_raw(dcmd_topic("hub0.dom16.7"), on)
        self.rig.wait_log(rf"Sparkplug: a DCMD on spBv1\.0/{GROUP}/DCMD/{NODE}/hub0/dom16/0, "
                          r"which names no device of this edge node \(its device id has several "
                          r"levels: a broker that turns the '\.' of topics into '/', as RabbitMQ "
                          r"does, needs another device_id_separator; docs/sparkplug\.md\)",
                          since=log)
        eventually(lambda: re.search(r'(?m)^ioportd_sparkplug_commands_total\{result='
                                     r'"unknown_device"\} 2$', self.rig.metrics()), 10,
                   lambda: self.rig.metrics())
        self.assertEqual(int(self.rig.ctl("get dom16:0")) & 0x0001, 0)
        # The host application saw the test's own DCMD of several levels too, a topic outside
        # Sparkplug's namespace: that one violation is the test's, on purpose.
        own = (f"[topic] topic outside the Sparkplug namespace: spBv1.0/{GROUP}/DCMD/{NODE}/"
               "hub0/dom16/0")
        eventually(lambda: own in self.host.violations, 10, lambda: self.host.violations)
        self.host.violations.remove(own)

    def test_device_ids_with_another_separator(self):
        # A RabbitMQ fleet (issue 49): device ids of one topic level whatever the broker does.
        self.rig.configure(HUB_MODULES, "  device_id_separator: _\n")
        mark = self.host.mark()
        self.rig.start_daemon()
        self.host.wait_message("DBIRTH", "hub0_dom16_0", since=mark, timeout=10)
        self.host.dcmd(GROUP, NODE, "hub0_dom16_0", [{"name": "out/1", "value": True}])
        eventually(lambda: int(self.rig.ctl("get dom16:0"), 0) & 0x0002, 10, "out/1 on")
        self.assertEqual(self.host.violations, [])

    def test_read_only_refuses_dcmd(self):
        self.rig.configure(HUB_MODULES, modbus_extra="  read_only: true\n")
        self.start()
        log = self.rig.log_mark()
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0",
                       [{"name": "out/3", "value": True, "datatype": "Boolean"}])
        self.host.dcmd(GROUP, NODE, "press.id2",
                       [{"name": "reset", "value": True, "datatype": "Boolean"}])
        self.barrier(self.rig)  # polls since: a write, had one been queued, went before them
        self.assertEqual(int(self.rig.ctl("get dom16:0")) & 0x0008, 0, "the coil was written")
        self.rig.wait_log(r"Sparkplug DCMD to hub0\.dom16\.0 refused: modbus\.read_only",
                          since=log)
        self.rig.wait_log(r"Sparkplug DCMD to press\.id2 refused: modbus\.read_only", since=log)
        self.assertIsNone(re.search(r"write by sparkplug", self.rig.log_text()[log:]))
        client = self.modbus(self.rig)
        try:
            self.assertEqual(client.write_coil(3, True, slave=1).exception_code, 1)
        finally:
            client.close()

    def test_ncmd_rebirth_requests_closer_than_a_second_are_served_once(self):
        self.start()
        mark, log = self.host.mark(), self.rig.log_mark()
        started = time.monotonic()
        rebirth = command_payload([("Node Control/Rebirth", "Boolean", True)])
        self.flood(f"spBv1.0/{GROUP}/NCMD/{NODE}", rebirth, 3000)
        # a barrier behind the flood: a refused DCMD's line comes once the NCMDs are handled
        self.host.dcmd(GROUP, NODE, "hub0.rgbdm.0",
                       [{"name": "colour", "value": 9, "datatype": "UInt8"}])
        self.rig.wait_log(r"DCMD hub0\.rgbdm\.0/colour = 9 refused", 30, since=log)
        # a request after the flood is still served, within the second
        after = self.host.mark()
        self.host.rebirth(GROUP, NODE)
        self.host.wait_message("NBIRTH", since=after, node=NODE, timeout=3)
        took = time.monotonic() - started
        births = self.host.since(mark, "NBIRTH", node=NODE)
        # by the node's own timestamps: the broker and a loaded machine add to the arrivals'
        gaps = [(b.timestamp - a.timestamp) / 1000 for a, b in zip(births, births[1:])]
        print(f"\n  3000 NCMD rebirths and one more in {took:.2f} s: {len(births)} NBIRTHs, "
              f"shortest gap {min(gaps, default=0):.2f} s", file=sys.stderr)
        self.assertLessEqual(len(births), took + 2)
        self.assertGreaterEqual(min(gaps, default=1), 0.99)
        lines = re.findall(r"rebirth asked for", self.rig.log_text()[log:])
        self.assertLessEqual(len(lines), 2)

    @covers("tck-id-operational-behavior-data-commands-rebirth-action-1")
    def test_a_rebirth_request_stops_data_until_the_births(self):
        self.start()
        mark = self.host.mark()
        self.host.rebirth(GROUP, NODE)
        first = self.host.wait_message("NBIRTH", since=mark, node=NODE)
        # A second request within the second after that NBIRTH waits for the second to end;
        # an input changed meanwhile goes out in the births, not as DDATA before them.
        asked = self.host.mark()
        self.host.rebirth(GROUP, NODE)
        self.rig.ctl("set dim16:0 0x0777")
        second = self.host.wait_message("NBIRTH", since=asked, node=NODE)
        between = [m for m in self.host.since(asked)[:second.index - asked]
                   if m.type in ("NDATA", "DDATA")]
        self.assertEqual(between, [], "DATA after the rebirth request, before its NBIRTH")
        self.assertGreaterEqual(second.timestamp - first.timestamp, 990)
        self.host.wait_metric("hub0.dim16.0", "word", 0x0777, since=second.index)

    def test_a_flood_of_bad_dcmds_logs_a_line(self):
        self.start()
        client = self.modbus(self.rig)
        try:
            log = self.rig.log_mark()
            bad = command_payload([("word", "UInt16", 70000)])
            started = time.monotonic()
            self.flood(dcmd_topic("hub0.dom16.0"), bad, 2000)
            mark = self.host.mark()
            slowest = self.timed_reads(client, self.served_after_a_flood(
                mark, "hub0.dom16.0", [{"name": "out/3", "value": True}]))
            self.host.wait_metric("hub0.dom16.0", "out/3", True, since=mark)
            took = time.monotonic() - started
            text = self.rig.log_text()[log:]
            lines = re.findall(r"DCMD hub0\.dom16\.0/word = 70000 refused", text)
            print(f"\n  2000 bad DCMDs in {took:.2f} s: {len(lines)} log line(s); slowest Modbus "
                  f"read {slowest * 1000:.1f} ms", file=sys.stderr)
            self.assertEqual(len(lines), 1, text[-3000:])
            self.assertLess(slowest, 0.2 * SLOWDOWN, "Modbus waited for the DCMDs")
            self.assertEqual(int(self.rig.ctl("get dom16:0")), 0x0008)
        finally:
            client.close()

    def test_a_dcmd_finding_the_write_queue_full_is_refused_and_never_applied(self):
        # one write may wait on hub0: of a DCMD's 17 metrics, those that find it taken are
        # refused at once (gateway.md §4), logged once, and never sent later
        self.rig.configure(HUB_MODULES, hub_extra="    max_pending_writes: 1\n")
        self.start()
        log = self.rig.log_mark()
        metrics = [{"name": f"out/{k}", "value": True} for k in range(16)]
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", metrics + [{"name": "word", "value": 0}])
        refused = r"Sparkplug DCMD hub0\.dom16\.0/\S+ = \S+ refused: 1 writes are waiting"
        self.rig.wait_log(refused, since=log)
        # a barrier: every metric's write ended (audited) or was refused before these polls
        self.barrier(self.rig)
        text = self.rig.log_text()[log:]
        written = re.findall(r"DCMD hub0\.dom16\.0/(\S+) = \S+: confirmed", text)
        metrics_text = self.rig.metrics()
        busy = int(re.search(r'ioportd_sparkplug_commands_total\{result="refused"\} (\d+)',
                             metrics_text).group(1))
        print(f"\n  DCMD of 17 metrics, max_pending_writes 1: {len(written)} written "
              f"({' '.join(written)}), {busy} refused, "
              f"{len(re.findall(refused, text))} log line(s)", file=sys.stderr)
        self.assertGreater(busy, 0)
        self.assertEqual(len(written) + busy, 17)
        self.assertEqual(len(re.findall(refused, text)), 1, "one line a minute")
        expected = 0
        for name in written:
            expected = 0 if name == "word" else expected | 1 << int(name.split("/")[1])
        self.assertEqual(int(self.rig.ctl("get dom16:0")), expected, "a refused write was sent")

    def test_broker_strings_cannot_forge_log_lines(self):
        self.start()
        log = self.rig.log_mark()
        fake = "2026-12-02 16:00:00.000 info FORGED by the broker"
        self.host.dcmd(GROUP, NODE, "hub0.rgbdm.0",
                       [{"name": "colour\n" + fake, "value": 3, "datatype": "UInt8"}])
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0",
                       [{"name": "word", "value": "1\r\n" + fake, "datatype": "String"}])
        self.rig.wait_log(r"FORGED by the broker = 3 refused", since=log)
        self.rig.wait_log(r"FORGED by the broker refused", since=log)
        text = self.rig.log_text()[log:]
        self.assertIsNone(re.search(r"(?m)^2026-12-02 16:00:00\.000 info FORGED", text), text)
        self.assertRegex(text, r"DCMD hub0\.rgbdm\.0/colour\\n2026-12-02 16:00:00\.000 info "
                               r"FORGED by the broker = 3 refused")
        self.assertRegex(text, r"DCMD hub0\.dom16\.0/word = 1\\r\\n2026-12-02 16:00:00\.000 "
                               r"info FORGED by the broker refused")
        # the events of /api/v1/state have them escaped the same way
        events = [e["text"] for e in self.rig.state()["events"] if "FORGED" in e["text"]]
        self.assertEqual(len(events), 2, events)
        self.assertTrue(all("\n" not in e and "\\n2026" in e for e in events), events)

    def test_a_reload_while_a_dcmd_is_in_flight_keeps_the_new_session_alive(self):
        self.start()
        log = self.rig.log_mark()
        self.rig.ctl("fault dom16:0 silent")
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0",
                       [{"name": f"out/{k}", "value": True} for k in range(6)])
        # the first write has failed; five more wait behind it, and hold the node that took them
        self.rig.wait_log(r"DCMD hub0\.dom16\.0/out/0 = true: (?!confirmed)", since=log)
        mark = self.host.mark()
        self.rig.configure(HUB_MODULES, "  client_id: ioportd-reloaded\n")
        self.rig.daemon.send_signal(signal.SIGHUP)
        reloaded = self.rig.wait_log(r"SIGHUP: reloaded", since=log).start()
        nbirth = self.host.wait_message("NBIRTH", since=mark, node=NODE, timeout=10)
        self.host.wait_message("DBIRTH", "hub0.dim16.0", since=nbirth.index, timeout=10)
        last = self.rig.wait_log(r"DCMD hub0\.dom16\.0/out/5 = true: (?!confirmed)", 15,
                                 since=log)
        self.assertGreater(last.start(), reloaded, "the DCMD was over before the reload")
        # the old node is gone with its last command; the new session still hears the links
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x0077")
        self.host.wait_metric("hub0.dim16.0", "word", 0x0077, since=mark)
        self.rig.ctl("fault dom16:0 none")


class Lifecycle(OwnDaemon):
    """A daemon of its own for each test: ends, restarts, the broker's comings and goings."""

    def deaths_after_sigterm(self, nbirth):
        """SIGTERM: the NDEATHs it brought (all of them: the barrier is a message of our own
        after them, on a topic we subscribe to), the node's own first, with the session's bdSeq
        and the time of the stop, not the will's of the CONNECT."""
        mark = self.host.mark()
        sent = time.time()
        took, code = self.rig.stop_daemon(signal.SIGTERM)
        self.assertEqual(code, 0)
        ndeath = self.host.wait_message("NDEATH", since=mark)
        self.assertEqual(ndeath.metric("bdSeq").value, nbirth.metric("bdSeq").value)
        self.assertGreaterEqual(ndeath.timestamp, int(sent * 1000) - 1,
                                "published at the stop, not the will made at CONNECT")
        print(f"\n  SIGTERM to exit: {took * 1000:.0f} ms", file=sys.stderr)
        self.assertLess(took, 0.45, "stop waited for the Sparkplug stop deadline (500 ms)")
        self.host.state("barrier", True, retain=False)
        self.host.wait_message("STATE", since=mark, node="barrier")
        return self.host.since(mark, "NDEATH")

    @covers("tck-id-operational-behavior-edge-node-intentional-disconnect-ndeath",
            "tck-id-operational-behavior-edge-node-intentional-disconnect-packet",
            "tck-id-payloads-ndeath-will-message-publisher",
            "tck-id-payloads-ndeath-will-message-publisher-disconnect-mqtt50")
    def test_sigterm_publishes_ndeath_with_the_session_bdseq(self):
        nbirth = self.start()
        self.rig.wait_log(r"mqtt: connected to \S+ as ioportd-plant1-box7 \(MQTT 5\)")
        # MQTT 5: the DISCONNECT after the node's NDEATH asks the broker for the will too
        # (Sparkplug 3.0), the same bdSeq, made at CONNECT.
        own, will = self.deaths_after_sigterm(nbirth)
        self.assertEqual(will.metric("bdSeq").value, own.metric("bdSeq").value)
        self.assertLess(will.timestamp, nbirth.timestamp + 1, "the will, made at CONNECT")

    @covers("tck-id-principles-persistence-clean-session-50",
            "tck-id-principles-persistence-clean-session-311",
            "tck-id-operational-behavior-edge-node-intentional-disconnect-ndeath",
            "tck-id-payloads-ndeath-will-message-publisher-disconnect-mqtt311")
    def test_a_broker_without_mqtt5_is_spoken_to_in_3_1_1(self):
        # The class's Mosquitto behind a front that refuses MQTT 5, as a broker from before it
        # does: the node asks for 5 (Clean Start, no session after the connection, nothing
        # larger than 64 KiB), then speaks 3.1.1 with Clean Session, which cannot ask for a
        # bound, and says so.
        front = Mqtt311Front(self.broker.port)
        front.start()
        self.addCleanup(front.close)
        self.rig.broker_url = f"mqtt://127.0.0.1:{front.port}"
        self.rig.configure(HUB_MODULES)
        nbirth = self.start()
        self.rig.wait_log(rf"mqtt: mqtt://127\.0\.0\.1:{front.port} refused MQTT 5, so MQTT "
                          r"3\.1\.1 with it from now on; a message larger than 65536 bytes is "
                          r"read in passing and refused")
        self.rig.wait_log(r"mqtt: connected to \S+ as ioportd-plant1-box7 \(MQTT 3\.1\.1\)")
        v5, v311 = front.connects[:2]
        self.assertEqual((v5["level"], v5["clean"], v5["client_id"]), (5, True, CLIENT_ID))
        self.assertEqual({k: v5["properties"].get(k) for k in (0x11, 0x27)},
                         {0x11: 0, 0x27: 65536}, "Session Expiry Interval, Maximum Packet Size")
        self.assertEqual((v311["level"], v311["clean"], v311["client_id"]), (4, True, CLIENT_ID))
        for connect in (v5, v311):
            self.assertEqual((connect["will"], connect["will_qos"], connect["will_retain"]),
                             (True, 1, False))
        # MQTT 3.1.1: its DISCONNECT discards the will, so one NDEATH, the node's own.
        self.assertEqual(len(self.deaths_after_sigterm(nbirth)), 1)

    @covers("tck-id-payloads-ndeath-will-message",
            "tck-id-message-flow-edge-node-birth-publish-will-message",
            "tck-id-message-flow-edge-node-birth-publish-will-message-payload",
            "tck-id-message-flow-edge-node-birth-publish-will-message-topic",
            "tck-id-topics-nbirth-bdseq-matching",
            "tck-id-payloads-nbirth-bdseq-repeat")
    def test_kill9_gives_the_will_with_the_session_bdseq(self):
        nbirth = self.start()
        mark = self.host.mark()
        self.rig.stop_daemon(signal.SIGKILL)
        ndeath = self.host.wait_message("NDEATH", since=mark, node=NODE)
        self.assertEqual((ndeath.group, ndeath.topic), (GROUP, f"spBv1.0/{GROUP}/NDEATH/{NODE}"))
        self.assertEqual(ndeath.metric("bdSeq").value, nbirth.metric("bdSeq").value)
        self.assertLess(ndeath.timestamp, nbirth.timestamp + 1, "the will, made at CONNECT")

    def test_broker_restart_new_session_with_next_bdseq(self):
        nbirth = self.start()
        bdseq = nbirth.metric("bdSeq").value
        client = self.modbus(self.rig)
        try:
            mark = self.host.mark()
            stopped = time.monotonic()
            self.broker.stop()
            self.broker.start()
            self.rig.wait_log(r"mqtt: .*reconnecting within 1 s")
            again = self.wait_births(mark)
            took = time.monotonic() - stopped
            self.assertEqual(again.metric("bdSeq").value, (bdseq + 1) % 256)
            self.assertGreater(took, 0.9, "the first reconnect comes after 1 s")
            self.assertLess(took, 5)
            # the node is alive in the new session
            mark = self.host.mark()
            self.rig.ctl("set dim16:0 0x0300")
            self.host.wait_metric("hub0.dim16.0", "word", 0x0300, since=mark)
            self.assertModbusAnswers(client)
        finally:
            client.close()

    def test_broker_down_at_start(self):
        self.broker.stop()
        try:
            self.rig.ctl("set dim16:0 0x1234")
            started = time.monotonic()
            self.rig.start_daemon()
            client = self.modbus(self.rig)
            try:
                # polling is not held up: the hub is online as soon as without MQTT (generous
                # bounds for a loaded machine; an unloaded one takes about 0.1 s)
                eventually(lambda: client.read_input_registers(1000, 1, slave=1).registers[0] == 1,
                           8, "hub online")
                asked = time.monotonic()
                regs = client.read_input_registers(0, 1, slave=1)
                self.assertLess(time.monotonic() - asked, 0.5 * SLOWDOWN, "Modbus waits for the broker")
                self.assertEqual(regs.registers[0], 0x1234)
                took = time.monotonic() - started
                print(f"\n  broker down: start to hub online and read {took:.2f} s",
                      file=sys.stderr)
            finally:
                client.close()
            # The first attempt failed; the next is 1 s later (and what it sends waits at the
            # broker for the host app, should that come back after the node).
            self.rig.wait_log(r"mqtt: cannot connect.*reconnecting within 1 s|"
                              r"mqtt: .*reconnecting within 1 s")
            connects, mark = self.host.connects, self.host.mark()
        finally:
            self.broker.start()
        self.host.wait(lambda: self.host.connects > connects, 5, "host app back")
        self.wait_births(mark)

    def test_a_stalled_broker_delays_neither_polling_nor_modbus(self):
        """The broker frozen (SIGSTOP) while inputs change: the node goes on publishing into
        the socket until its buffers fill and its queue drops, but Modbus answers at once and
        the modules stay freshly polled."""
        self.start()
        client = self.modbus(self.rig)
        try:
            os.kill(self.broker.process.pid, signal.SIGSTOP)
            try:
                # The broker stays stopped until every check below is done: a poll or a Modbus
                # answer that waited for it would not come at all, so each is awaited as an
                # event (within a deadline) rather than timed against the machine's pace.
                slowest, latest = 0.0, 0.0
                until = time.monotonic() + 3
                word = 0
                while time.monotonic() < until:
                    word = (word + 1) & 0xFFFF
                    self.rig.ctl(f"set dim16:0 {word}")
                    set_at = time.monotonic()

                    def polled():
                        nonlocal slowest
                        asked = time.monotonic()
                        regs = client.read_input_registers(0, 1, slave=1)
                        slowest = max(slowest, time.monotonic() - asked)
                        # No answer is Modbus waiting for the broker; an exception is an answer
                        # (dim16 0 briefly offline on a busy machine): not yet.
                        self.assertNotIsInstance(regs, ModbusIOException,
                                                 "Modbus waited for the broker")
                        return not regs.isError() and regs.registers[0] == word
                    eventually(polled, 10, f"dim16 0 word {word} polled with the broker stopped")
                    latest = max(latest, time.monotonic() - set_at)
                print(f"\n  broker stalled: slowest Modbus read {slowest * 1000:.1f} ms, a set "
                      f"polled and read back within {latest * 1000:.0f} ms", file=sys.stderr)
            finally:
                os.kill(self.broker.process.pid, signal.SIGCONT)
        finally:
            client.close()
        # and the session goes on (or, had it been lost, a new one begins) with the last word
        self.host.wait_metric("hub0.dim16.0", "word", word, timeout=15)

    @covers("tck-id-message-flow-edge-node-birth-publish-phid-wait",
            "tck-id-message-flow-edge-node-birth-publish-phid-wait-id",
            "tck-id-message-flow-edge-node-birth-publish-phid-wait-online",
            "tck-id-message-flow-edge-node-birth-publish-phid-wait-timestamp",
            "tck-id-message-flow-edge-node-birth-publish-phid-offline",
            "tck-id-operational-behavior-edge-node-termination-host-offline",
            "tck-id-operational-behavior-edge-node-termination-host-offline-timestamp",
            "tck-id-operational-behavior-edge-node-birth-sequence-wait")
    def test_primary_host_gates_births(self):
        self.host.state("scada", False)  # a retained STATE offline from before
        self.rig.configure(HUB_MODULES, "  primary_host_id: scada\n")
        mark = self.host.mark()
        self.rig.start_daemon()
        self.rig.wait_log(r"mqtt: connected to")
        # Not the primary host's: another host id online, and an online STATE older than the
        # retained offline one.
        log = self.rig.log_mark()
        self.host.state("other", True, retain=False)
        self.host.state("scada", True, retain=False, timestamp=1)
        self.rig.wait_log(r"STATE of scada ignored: its timestamp 1 is older than the last one",
                          5, log)
        # the barrier: a STATE it cannot read, which it says it got
        self.host.publish_raw("spBv1.0/STATE/scada", b"not json")
        self.rig.wait_log(r"STATE of scada refused: not JSON")
        self.assertEqual(self.host.since(mark, node=NODE), [], "nothing before STATE online")
        self.host.state("scada", True)
        first = self.wait_births(mark)
        self.assertEqual(first.seq, 0)
        # A stale offline STATE (older than the online one) changes nothing (Sparkplug 3.0,
        # tck-id-operational-behavior-edge-node-termination-host-offline-timestamp).
        # (Its log line is the one above's, held back within the minute.)
        mark = self.host.mark()
        self.host.state("scada", False, retain=False, timestamp=1)
        self.barrier(self.rig)
        self.assertEqual(self.host.since(mark, "NDEATH"), [])
        # The host goes offline: the session ends (NDEATH, DISCONNECT) and the node connects
        # again, to this broker, its only one (Sparkplug 3.0 §5.5,
        # tck-id-operational-behavior-edge-node-termination-host-offline, -reconnect); it waits
        # there for the host, and a new session (the next bdSeq) begins when it is back.
        mark = self.host.mark()
        self.host.state("scada", False)
        death = self.host.wait_message("NDEATH", node=NODE, since=mark, timeout=10)
        self.assertEqual(death.metric("bdSeq").value, first.metric("bdSeq").value)
        self.rig.wait_log(r"the primary host scada is offline on this broker; NDEATH, and "
                          r"connecting to mqtt://127\.0\.0\.1:\d+ again")
        self.host.state("scada", True)
        again = self.wait_births(mark)
        self.assertEqual(again.metric("bdSeq").value, (first.metric("bdSeq").value + 1) % 256)
        self.host.publish_raw("spBv1.0/STATE/scada", b"", retain=True)  # clear the retained one

    def test_sighup(self):
        self.start()
        mark, log = self.host.mark(), self.rig.log_mark()
        self.rig.daemon.send_signal(signal.SIGHUP)
        self.rig.wait_log(r"SIGHUP: reloaded", since=log)
        self.rig.ctl("set dim16:0 0x0042")
        self.host.wait_metric("hub0.dim16.0", "word", 0x0042, since=mark)
        self.assertEqual(self.host.since(mark, "NBIRTH"), [], "unchanged: the session is kept")
        self.assertEqual(self.rebirths(mark), [])
        self.rig.configure(HUB_MODULES + ["mux8m:0"])
        mark, log = self.host.mark(), self.rig.log_mark()
        self.rig.daemon.send_signal(signal.SIGHUP)
        self.rig.wait_log(r"SIGHUP: reloaded", since=log)
        self.wait_births(mark, devices=list(METRICS))
        self.assertEqual(self.host.since(mark, "NDEATH"), [])
        mux = self.host.wait_message("DBIRTH", "hub0.mux8m.0", since=mark)
        self.assertEqual([(m.name, m.datatype) for m in mux.metrics],
                         [("pos", 5), ("neg", 5)])
        self.host.dcmd(GROUP, NODE, "hub0.mux8m.0", [{"name": "pos", "value": 3}])
        self.host.wait_metric("hub0.mux8m.0", "pos", 3, since=mark)
        self.assertEqual(int(self.rig.ctl("get mux8m:0")) >> 8, 3)


def float32(value):
    return struct.unpack("<f", struct.pack("<f", value))[0]


# gateway.md §6.1: a name, a unit and a scale on acm3p 0's channel 0, a name on an input.
TAGS = {"acm3p:0": ', name: "boiler 1", channels: { 0: { name: "supply temperature", '
                   'unit: "°C", scale: [0, 100, -20, 150] } }',
        "dim16:0": ', inputs: { 2: "door open" }'}


class Tags(OwnDaemon):
    """Names, units and scales (gateway.md §6.1, issue 27): value/<ch> in engineering units, the
    DBIRTH's metric properties Ignition applies, and a reload that renames with a rebirth."""

    def births_of(self, mark, device):
        return self.host.wait_message("DBIRTH", device, since=mark, timeout=10)

    @covers("gateway.md §6.1", "tck-id-payloads-propertyset-keys-array-size",
            "tck-id-payloads-propertyset-values-array-size",
            "tck-id-payloads-metric-propertyvalue-type-type",
            "tck-id-payloads-metric-propertyvalue-type-value",
            "tck-id-payloads-metric-propertyvalue-type-req")
    def test_births_carry_names_units_and_ranges_as_properties(self):
        self.rig.configure(HUB_MODULES, module_extra=TAGS)
        self.rig.ctl("set acm3p:0 13208 41203 0")
        mark = self.host.mark()
        self.start()
        acm = self.births_of(mark, "hub0.acm3p.0")
        value0, value1, raw0 = acm.metric("value/0"), acm.metric("value/1"), acm.metric("raw/0")
        self.assertEqual(value0.properties, {
            "engUnit": "°C", "engLow": -20.0, "engHigh": 150.0,
            "documentation": "boiler 1: supply temperature"})
        self.assertEqual(value1.properties, {
            "engUnit": "%", "engLow": 0.0, "engHigh": 100.0, "documentation": "boiler 1"})
        self.assertEqual(raw0.properties, {"documentation": "boiler 1: supply temperature"})
        # Metric names stay as §5.5 says: a rename never breaks a host's history.
        self.assertEqual(value0.value, float32(-20 + 13208 / 65535 * 100 * 1.7))
        self.assertEqual(value1.value, float32(41203 / 65535 * 100))
        dim = self.births_of(mark, "hub0.dim16.0")
        self.assertEqual(dim.metric("in/2").properties, {"documentation": "dim16 0: door open"})
        self.assertEqual(dim.metric("in/3").properties, {})
        # DATA is scaled alike and carries no properties: they are the birth's.
        mark = self.host.mark()
        self.rig.ctl("set acm3p:0 32768 41203 0")
        data = self.host.wait_metric("hub0.acm3p.0", "value/0",
                                     float32(-20 + 32768 / 65535 * 100 * 1.7), since=mark)
        self.assertTrue(all(not m.properties for m in data.metrics))

    @covers("gateway.md §6.1")
    def test_a_reload_renames_and_rescales_with_a_rebirth(self):
        self.rig.configure(HUB_MODULES, module_extra=TAGS)
        self.rig.ctl("set acm3p:0 32768 0 0")
        nbirth = self.start()
        bdseq = nbirth.metric("bdSeq").value
        renamed = dict(TAGS, **{"acm3p:0": ', name: "boiler 2", channels: { 0: { name: '
                                           '"supply", unit: kPa, scale: [0, 100, 0, 1000] } }'})
        self.rig.configure(HUB_MODULES, module_extra=renamed)
        mark, log = self.host.mark(), self.rig.log_mark()
        self.rig.daemon.send_signal(signal.SIGHUP)
        self.rig.wait_log(r"names, units or scales changed: hub0", since=log)
        self.rig.wait_log(r"Sparkplug: names, units or scales changed; new births", since=log)
        again = self.wait_births(mark)
        self.assertEqual(again.metric("bdSeq").value, bdseq, "the same session")
        self.assertEqual(self.host.since(mark, "NDEATH"), [])
        acm = self.births_of(mark, "hub0.acm3p.0")
        self.assertEqual(acm.metric("value/0").properties, {
            "engUnit": "kPa", "engLow": 0.0, "engHigh": 1000.0,
            "documentation": "boiler 2: supply"})
        self.assertEqual(acm.metric("value/0").value, float32(32768 / 65535 * 100 * 10))
        # Polling went on; the port was not reopened.
        self.assertEqual(self.host.since(mark, "DDEATH"), [])


    def test_the_properties_rule_finds_each_break(self):
        """The host app's `properties` rule on a canned NBIRTH of another node: it must catch
        what it claims to check, or the ids it covers are not checked."""
        now = int(time.time() * 1000)
        payload = pb.Payload(timestamp=now, seq=0)
        for name, datatype, value in (("bdSeq", "Int64", 0),
                                      ("Node Control/Rebirth", "Boolean", False)):
            encode_value(payload.metrics.add(name=name, timestamp=now), datatype, value)
        broken = {"keys": None, "untyped": None, "mistyped": None}
        for alias, name in enumerate(broken, start=1):
            m = payload.metrics.add(name=name, alias=alias, timestamp=now)
            encode_value(m, "Float", 1.0)
            m.properties.keys.append("engUnit")
            v = m.properties.values.add()
            if name == "keys":
                m.properties.keys.append("engLow")  # two keys, one value
                v.type, v.string_value = 12, "°C"
            elif name == "untyped":
                v.string_value = "°C"
            else:
                v.type, v.string_value = 10, "°C"  # a Double in string_value
        before = len(self.host.violations)
        with self.host._cond:
            self.host._receive("spBv1.0/canned/NBIRTH/rules", payload.SerializeToString())
        new, self.host.violations[before:] = self.host.violations[before:], []
        found = [v for v in new if v.startswith("[properties]")]
        self.assertEqual(len(found), 3, new)
        for name in broken:
            self.assertTrue(any(f"{name}: " in v for v in found), (name, found))


class StoreAndForward(OwnDaemon):
    """gateway.md §6.2 (issue 26): what changes while no broker takes it is kept in the store and
    forwarded after the next births, as historical DDATA with its acquisition timestamps, oldest
    first; a record leaves the store once the broker has it; kill -9 loses nothing written."""

    WORDS = [0x0001, 0x0003, 0x0007, 0x000F, 0x001F, 0x003F]
    MQTT_EXTRA = ""  # more keys under mqtt:
    WORD = "word"  # dim16:0's word as the host knows it

    def setUp(self):
        self.store = os.path.join(tempfile.mkdtemp(dir=self.dir), "sparkplug")
        self.rig = self.new_rig(
            mqtt_extra=f"  store: {{ path: {self.store}, forward_rate: 20 }}\n" + self.MQTT_EXTRA)

    def tearDown(self):
        if self.broker.process is None:
            self.broker.start()
        super().tearDown()

    def store_state(self):
        return self.rig.state()["sparkplug"]["store"]

    def broker_back(self):
        """The broker started again, and the host app connected to it again (what the node sent
        in between waited at the broker in the host app's session)."""
        connects = self.host.connects
        self.broker.start()
        self.host.wait(lambda: self.host.connects > connects, 10, "the host app back")

    def broker_away(self):
        self.broker.stop()
        eventually(lambda: not self.rig.state()["sparkplug"]["connected"], 15,
                   "the node notices the broker is gone")

    @staticmethod
    def word_is(client, word):
        """dim16:0 reads as `word`; an exception (dim16 0 briefly offline on a busy machine) is
        not yet."""
        regs = client.read_input_registers(0, 1, slave=1)
        return not regs.isError() and regs.registers[0] == word

    def change_while_away(self, words):
        """Sets dim16:0 to each word in turn, each read back over Modbus (so polled) before the
        next."""
        client = self.modbus(self.rig)
        try:
            for word in words:
                self.rig.ctl(f"set dim16:0 {word:#06x}")
                eventually(lambda: self.word_is(client, word), 30, f"dim16:0 read as {word:#06x}")
        finally:
            client.close()

    def history(self, mark):
        """(value, timestamp) of every historical `word` of dim16:0 since `mark`, in order."""
        return [(value, stamp) for m in self.host.since(mark, "DDATA", "hub0.dim16.0")
                for name, value, stamp in m.historical if name == self.WORD]

    def written_history(self, mark):
        """history()'s values, each run of one value once, and without a leading 0 (dim16:0's word
        before the test's changes). The node publishes the current word again when the module's
        status changes; under load a poll that timed out did that during an outage once, and the
        0 it stored is history like the rest, truthfully stamped before the changes."""
        values = [value for value, _ in self.history(mark)]
        runs = [value for i, value in enumerate(values) if i == 0 or value != values[i - 1]]
        return runs[1:] if runs[:1] == [0] else runs

    def check_history_form(self, mark):
        """What a historical DDATA looks like: flat metrics, each is_historical."""
        for m in self.host.since(mark, "DDATA", "hub0.dim16.0"):
            if m.historical:
                self.assertTrue(all(metric.is_historical and metric.template is None
                                    for metric in m.metrics), m.metrics)

    @covers("gateway.md §6.2")
    def test_changes_while_the_broker_is_away_arrive_as_history_in_order(self):
        self.start()
        self.broker_away()
        before = int(time.time() * 1000)
        self.change_while_away(self.WORDS)
        stored = eventually(lambda: self.store_state()["records"] >= len(self.WORDS) and
                            self.store_state(), 5, "the changes in the store")
        self.assertLessEqual(before, stored["oldest"])
        mark = self.host.mark()
        self.broker_back()
        self.wait_births(mark)
        eventually(lambda: self.written_history(mark) == self.WORDS, 20,
                   lambda: f"history of dim16:0 word: {self.history(mark)}")
        self.check_history_form(mark)
        stamps = [stamp for _, stamp in self.history(mark)]
        self.assertEqual(stamps, sorted(stamps), "oldest first")
        nbirth = self.host.since(mark, "NBIRTH")[0]
        first_change = next(stamp for value, stamp in self.history(mark) if value == self.WORDS[0])
        self.assertTrue(before <= first_change and stamps[-1] <= nbirth.timestamp,
                        "acquisition timestamps, from before the births")
        # The births carry the current values; history never changes the host's view.
        dbirth = self.host.since(mark, "DBIRTH", "hub0.dim16.0")[0]
        self.assertEqual(dbirth.resolved[self.WORD], self.WORDS[-1])
        self.assertEqual(self.value("hub0.dim16.0", self.WORD), self.WORDS[-1])
        # Emptied once the broker provably has them, and said so.
        state = eventually(lambda: self.store_state()["records"] == 0 and self.store_state(), 10,
                           "the store emptied")
        # On disk too, mark written: a restart (even after kill -9) forwards nothing again.
        eventually(lambda: os.path.exists(os.path.join(self.store, "delivered")) and not any(
            name.endswith(".seg") for name in os.listdir(self.store)), 5,
            lambda: f"the store's files: {os.listdir(self.store)}")
        self.assertGreaterEqual(state["forwarded"], len(self.WORDS))
        self.assertIsNone(state["oldest"])
        self.rig.wait_log(r"Sparkplug: forwarding \d+ stored record\(s\)", 1)
        self.rig.wait_log(r"Sparkplug: forwarded \d+ stored record\(s\) in", 10)
        metrics = self.rig.metrics()
        self.assertIn("ioportd_sparkplug_store_records 0\n", metrics)
        forwarded = re.search(r"^ioportd_sparkplug_forwarded_total (\d+)$", metrics, re.M)
        self.assertGreaterEqual(int(forwarded.group(1)), len(self.WORDS))
        self.assertRegex(metrics, r"(?m)^ioportd_sparkplug_store_dropped_total 0$")
        self.assertRegex(metrics, r"(?m)^ioportd_sparkplug_store_bytes \d+$")
        self.rig.daemon.kill()
        self.rig.daemon.wait(5)
        self.rig.start_daemon()
        self.rig.wait_log(r"Sparkplug store \S+: 0 record\(s\) to forward", 5)

    def test_a_start_stores_nothing_that_the_births_carry(self):
        # Before (issue 49): every start forwarded about 9 historical DDATA that repeated the
        # DBIRTHs' values, as the first reads came before the first CONNACK and went to the
        # store; a historian got a duplicate sample per metric per restart. The broker is away
        # at the start here, so that every first read comes before any session.
        self.broker.stop()
        self.rig.start_daemon()
        eventually(lambda: all(m["status_text"] == "online" for link in self.rig.state()["links"]
                               for m in link["modules"]), 10, "every module polled")
        mark = self.host.mark()
        self.broker_back()
        self.wait_births(mark)
        store = self.store_state()
        self.assertEqual((store["records"], store["forwarded"]), (0, 0), store)
        self.assertEqual([m for m in self.host.since(mark, "DDATA") if m.historical], [])
        # What changes after the first reads is history as ever.
        self.broker_away()
        self.change_while_away(self.WORDS[:2])
        mark = self.host.mark()
        self.broker_back()
        self.wait_births(mark)
        eventually(lambda: self.written_history(mark) == self.WORDS[:2], 20,
                   lambda: f"history of dim16:0 word: {self.history(mark)}")

    def test_nothing_is_published_before_the_subscriptions_are_acknowledged(self):
        # Before (issue 49): the births, and live DDATA after them, went out right after the
        # CONNACK. RabbitMQ takes the CONNECT of a session whose queue's node is down and then
        # closes the connection at the SUBSCRIBE: a change published live in that moment was
        # lost with the connection, in no store (mqtt_fleet, a kill of node 1 without the
        # mirrored policy). Now what changes before the SUBACK is stored, and goes as history.
        front = SubackHoldingFront(self.broker.port)
        front.start()
        self.addCleanup(front.close)
        self.addCleanup(front.release.set)
        self.rig.broker_url = f"mqtt://127.0.0.1:{front.port}"
        self.rig.configure(HUB_MODULES, f"  store: {{ path: {self.store}, forward_rate: 20 }}\n"
                           + self.MQTT_EXTRA)
        mark = self.host.mark()
        self.rig.start_daemon()
        eventually(lambda: sum(kind == 8 for kind, _ in front.sent) >= 3, 10,
                   lambda: f"the node's SUBSCRIBEs: {front.sent}")
        eventually(lambda: all(m["status_text"] == "online" for link in self.rig.state()["links"]
                               for m in link["modules"]), 10, "every module polled")
        self.change_while_away(self.WORDS[:2])
        eventually(lambda: self.store_state()["records"] >= 2, 5,
                   lambda: f"the changes in the store: {self.store_state()}")
        self.assertEqual([topic for kind, topic in front.sent if kind == 3], [],
                         "published before the SUBACK")
        front.release.set()
        self.wait_births(mark)
        eventually(lambda: self.written_history(mark) == self.WORDS[:2], 20,
                   lambda: f"history of dim16:0 word: {self.history(mark)}")

    def test_first_reads_that_change_before_the_births_are_history(self):
        # Before: a start while the broker was away kept the first reads out of the store, for
        # the DBIRTH to carry; a value that changed before the birth was in none and was lost
        # (soak_every_path under load: a value set just before a kill -9 in the outage, read
        # first by the next run, changed before the broker came back).
        self.rig.ctl(f"set dim16:0 {self.WORDS[0]:#06x}")
        self.broker.stop()
        self.rig.start_daemon()
        eventually(lambda: all(m["status_text"] == "online" for link in self.rig.state()["links"]
                               for m in link["modules"]), 10, "every module polled")
        self.change_while_away(self.WORDS[1:3])
        mark = self.host.mark()
        self.broker_back()
        self.wait_births(mark)
        eventually(lambda: self.written_history(mark) == self.WORDS[:3], 20,
                   lambda: f"history of dim16:0 word: {self.history(mark)}")

    def test_bdseq_goes_on_across_a_restart_and_refused_connects_spend_none(self):
        # Before (issue 49): every process began at bdSeq 0, so a late will of the last run could
        # carry the new session's; and every refused TCP connect spent one (0 -> 3 after a 3 s
        # outage), though no broker saw its CONNECT. The next bdSeq is kept beside the store.
        # Each run first meets a port where no broker listens (its CONNECT refused at TCP), then
        # the class's broker.
        dead = free_port()
        self.rig.broker_urls = [f"mqtt://127.0.0.1:{p}" for p in (dead, self.broker.port)]
        self.rig.configure(HUB_MODULES, f"  store: {{ path: {self.store}, forward_rate: 20 }}\n"
                           + self.MQTT_EXTRA)
        for expected in (0, 1):  # a store of its own: the first run begins at 0
            mark = self.host.mark()
            self.rig.start_daemon()  # the log from here on is this run's
            self.rig.wait_log(rf"mqtt: cannot connect to mqtt://127\.0\.0\.1:{dead}: Connection "
                              r"refused")
            self.assertEqual(self.wait_births(mark).metric("bdSeq").value, expected)
            self.rig.stop_daemon(signal.SIGTERM)
        with open(os.path.join(self.store, "bdseq")) as f:
            self.assertEqual(f.read(), "2\n")

    STOPS = 20  # clean broker stops in test_a_value_in_flight_at_a_clean_broker_stop_…

    def published(self):
        """Messages the node has handed to its broker connection."""
        found = re.search(r"(?m)^ioportd_mqtt_messages_published_total (\d+)$", self.rig.metrics())
        return int(found.group(1))

    def word_data(self, mark):
        """(value, timestamp, historical) of dim16:0's word in every DDATA since `mark`."""
        found = []
        for m in self.host.since(mark, "DDATA", "hub0.dim16.0"):
            if self.WORD in m.resolved:
                found.append((m.resolved[self.WORD], m.timestamp, False))
            found += [(value, stamp, True) for name, value, stamp in m.historical
                      if name == self.WORD]
        return found

    @covers("gateway.md §6.2")
    def test_a_value_in_flight_at_a_clean_broker_stop_arrives_live_or_as_history(self):
        # Before: live DDATA (QoS 0) published just as the broker stopped cleanly went into a
        # connection the broker never read again, and was not stored, as a session was up: the
        # host never had the value (docs/sparkplug.md promised "a clean broker stop leaves no
        # gap"). The broker is frozen (SIGSTOP) so that it reads nothing, the word changes, the
        # node publishes it, and the broker is told to stop (SIGTERM, then SIGCONT): it exits
        # without reading it. Then another word, stored while the broker is away.
        self.start()
        client = self.modbus(self.rig)
        mark = self.host.mark()
        words = []
        try:
            for stop in range(self.STOPS):
                in_flight, meanwhile = 0x0100 + 2 * stop, 0x0101 + 2 * stop
                words += [in_flight, meanwhile]
                before, pid = self.published(), self.broker.process.pid
                os.kill(pid, signal.SIGSTOP)
                try:
                    self.rig.ctl(f"set dim16:0 {in_flight:#06x}")
                    eventually(lambda: self.word_is(client, in_flight), 30,
                               f"dim16:0 read as {in_flight:#06x}")
                    eventually(lambda: self.published() > before, 5,
                               f"the DDATA of {in_flight:#06x} published")
                    os.kill(pid, signal.SIGTERM)
                finally:
                    os.kill(pid, signal.SIGCONT)
                self.broker.process.wait(10 * SLOWDOWN)
                eventually(lambda: not self.rig.state()["sparkplug"]["connected"], 15,
                           "the node notices the broker is gone")
                self.change_while_away([meanwhile])
                births = self.host.mark()
                self.broker_back()
                self.wait_births(births)
        finally:
            client.close()

        def arrived():
            return {value for value, _, _ in self.word_data(mark)} >= set(words)
        eventually(arrived, 20, lambda: "never arrived, live or as history: " + ", ".join(
            f"{w:#06x}" for w in sorted(set(words) - {v for v, _, _ in self.word_data(mark)})))
        data = self.word_data(mark)
        # Each in its order: the value in flight was read before the one stored after it.
        first = {}
        for value, stamp, _ in data:
            first.setdefault(value, stamp)
        for stop in range(self.STOPS):
            self.assertLess(first[words[2 * stop]], first[words[2 * stop + 1]])
        live = {value for value, _, historical in data if not historical}
        history = [value for value, _, historical in data if historical]
        in_flight = words[0::2]
        print(f"\n  {self.STOPS} clean broker stops: {sum(w in live for w in in_flight)} value(s) "
              f"in flight arrived live, {sum(w not in live for w in in_flight)} only as history; "
              f"{sum(w in live for w in history)} sent both ways", file=sys.stderr)
        self.check_history_form(mark)

    @covers("gateway.md §6.2")
    def test_values_sent_to_a_silent_broker_arrive_as_history(self):
        # A broker that stops answering without closing the connection (frozen here, a pulled
        # cable in the field) is found out when keepalive (5 s) runs out. Before, the live DDATA
        # of that time, published into a connection nobody read again, were lost from the
        # history; now they stay unproven and are stored when the connection is given up. The
        # broker then exits without reading them (SIGTERM, then SIGCONT).
        self.start()
        mark = self.host.mark()
        pid = self.broker.process.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            self.change_while_away(self.WORDS)
            eventually(lambda: not self.rig.state()["sparkplug"]["connected"], 15,
                       "the node gives the silent broker up")
            os.kill(pid, signal.SIGTERM)
        finally:
            os.kill(pid, signal.SIGCONT)
        self.broker.process.wait(10 * SLOWDOWN)
        births = self.host.mark()
        self.broker_back()
        self.wait_births(births)
        eventually(lambda: self.written_history(mark) == self.WORDS, 20,
                   lambda: f"history of dim16:0 word: {self.history(mark)}")
        self.rig.wait_log(r"Sparkplug: [1-9]\d* live DDATA the broker had not proven it read kept "
                          r"in the store", 1)

    def test_live_data_the_broker_proved_it_read_is_not_sent_again(self):
        # The other side of the test above: a live DDATA is let go once the SUBACK of a later
        # SUBSCRIBE proves the broker read it, so a broker stopped after that has it once, not
        # again as history.
        self.start()
        offset = os.path.getsize(self.broker.log)
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x0ace")
        self.host.wait_metric("hub0.dim16.0", self.WORD, 0x0ace, since=mark)

        def proven():
            with open(self.broker.log, errors="replace") as f:
                f.seek(offset)
                text = f.read()
            ddata = text.find(f"'spBv1.0/{GROUP}/DDATA/{NODE}/hub0.dim16.0'")
            return ddata >= 0 and f"Sending SUBACK to {CLIENT_ID}" in text[ddata:]
        eventually(proven, 5, "a SUBACK to the node after its DDATA")
        self.broker_away()
        births = self.host.mark()
        self.broker_back()
        self.wait_births(births)
        eventually(lambda: self.store_state()["records"] == 0, 10, "the store empty")
        self.assertNotIn(0x0ace, [value for value, _ in self.history(mark)])

    def test_kill_9_in_the_outage_loses_nothing_written(self):
        self.start()
        self.broker_away()
        self.change_while_away(self.WORDS[:3])
        eventually(lambda: self.store_state()["records"] >= 3, 5, "the changes in the store")
        self.rig.daemon.kill()
        self.rig.daemon.wait(5)
        mark = self.host.mark()
        self.broker_back()
        self.rig.start_daemon()
        self.rig.wait_log(r"Sparkplug store \S+: [3-9]\d* record\(s\) to forward", 5)
        self.wait_births(mark)
        eventually(lambda: self.written_history(mark) == self.WORDS[:3], 20,
                   lambda: f"history of dim16:0 word: {self.history(mark)}")


# gateway.md §7.2: each device's template, by module type.
TEMPLATE_OF = {"hub0.dim16.0": "dim16", "hub0.dom16.0": "dom16", "hub0.acm3p.0": "acm3p",
               "hub0.rgbdm.0": "rgbdm", "hub0.mux8m.0": "mux8m", "press.id2": "id2"}
TEMPLATES = "  templates: true\n"


class TemplatesStoreAndForward(StoreAndForward):
    """gateway.md §7.2 with §6.2 (issue 41): with templates, what changed while the broker was
    away is forwarded as instances of the device's template, is_historical, with the original
    timestamps, oldest first."""
    MQTT_EXTRA = TEMPLATES
    WORD = "dim16/word"
    test_kill_9_in_the_outage_loses_nothing_written = None  # the store is the same: once is enough

    def check_history_form(self, mark):
        for m in self.host.since(mark, "DDATA", "hub0.dim16.0"):
            if not m.historical:
                continue
            self.assertEqual(len(m.metrics), 1, m.metrics)
            instance = m.metrics[0]
            self.assertIsNone(instance.name, "by the instance's alias")
            self.assertEqual(instance.alias, self.host.alias(GROUP, NODE, "hub0.dim16.0", "dim16"))
            self.assertTrue(instance.is_historical)
            self.assertEqual((instance.template.ref, instance.template.is_definition),
                             ("dim16", False))
            self.assertTrue(all(member.is_historical and member.timestamp
                                for member in instance.template.members))


class Templates(OwnDaemon):
    """Sparkplug templates (gateway.md §7.2, issue 41): NBIRTH defines a template per module type
    configured, DBIRTH is one instance per module with every member, DDATA the instance with the
    members that changed, DCMD writes an instance's members (as Ignition's MQTT Engine writes a
    UDT member) or flat names, and a reload that changes the set of types rebirths."""

    EXTRA = TEMPLATES + "  deadband: 1.0\n"

    def setUp(self):
        self.rig = self.new_rig(mqtt_extra=self.EXTRA)

    def instance_of(self, message):
        self.assertEqual(len(message.metrics), 1, message.metrics)
        return message.metrics[0]

    def definitions(self, nbirth):
        return {m.name: m for m in nbirth.metrics if m.template is not None}

    @covers("gateway.md §7.2", "tck-id-payloads-template-definition-nbirth",
            "tck-id-payloads-template-definition-members",
            "tck-id-payloads-template-instance-members-birth",
            "tck-id-payloads-template-definition-is-definition",
            "tck-id-payloads-template-instance-is-definition",
            "tck-id-payloads-template-definition-ref", "tck-id-payloads-template-instance-ref",
            "tck-id-payloads-template-version")
    def test_births_define_a_template_per_type_and_an_instance_per_module(self):
        self.rig.configure(HUB_MODULES, mqtt_extra=self.EXTRA, module_extra=TAGS)
        self.rig.ctl("set dim16:0 0x0005")
        self.rig.ctl("set acm3p:0 13208 41203 0")
        self.rig.id2("set count 7")
        nbirth = self.start()
        definitions = self.definitions(nbirth)
        self.assertEqual(sorted(definitions), ["_types_/acm3p", "_types_/dim16", "_types_/dom16",
                                               "_types_/id2", "_types_/rgbdm"])
        for device, type_ in TEMPLATE_OF.items():
            if device == "hub0.mux8m.0":
                continue
            definition = definitions[f"_types_/{type_}"]
            self.assertEqual((definition.datatype, definition.alias), (19, None))
            t = definition.template
            self.assertEqual((t.is_definition, t.version, t.ref), (True, "1", None))
            self.assertEqual([(m.name, m.datatype) for m in t.members],
                             [(n, TYPE_NUMBERS[d]) for n, d in METRICS[device]])
            self.assertTrue(all(m.is_null and m.alias is None for m in t.members),
                            "a definition has names and datatypes, no values")
            dbirth = self.host.since(nbirth.index, "DBIRTH", device)[0]
            instance = self.instance_of(dbirth)
            self.assertEqual((instance.name, instance.datatype), (type_, 19))
            self.assertIsNotNone(instance.alias)
            self.assertIs(instance.template.is_definition, False, "is_definition, present")
            self.assertEqual((instance.template.ref, instance.template.version), (type_, None))
            self.assertEqual([(m.name, m.datatype) for m in instance.template.members],
                             [(n, TYPE_NUMBERS[d]) for n, d in METRICS[device]])
            self.assertTrue(all(m.has_value and m.alias is None and m.timestamp
                                for m in instance.template.members))
        dim = self.host.since(nbirth.index, "DBIRTH", "hub0.dim16.0")[0]
        self.assertEqual(dim.resolved["dim16/word"], 5)
        self.assertEqual([dim.resolved[f"dim16/in/{k}"] for k in range(3)], [True, False, True])
        members = {m.name: m for m in self.instance_of(dim).template.members}
        self.assertEqual(members["in/2"].properties, {"documentation": "dim16 0: door open"})
        acm = {m.name: m for m in self.instance_of(
            self.host.since(nbirth.index, "DBIRTH", "hub0.acm3p.0")[0]).template.members}
        self.assertEqual(acm["value/0"].properties, {
            "engUnit": "°C", "engLow": -20.0, "engHigh": 150.0,
            "documentation": "boiler 1: supply temperature"})
        self.assertEqual(acm["value/0"].value, float32(-20 + 13208 / 65535 * 100 * 1.7))
        self.assertEqual(self.value("press.id2", "id2/count"), 7)

    @covers("gateway.md §7.2", "tck-id-payloads-template-instance-members-data")
    def test_ddata_is_the_instance_with_only_the_changed_members(self):
        self.rig.ctl("set acm3p:0 1000 2000 100")  # channel 2 at 100: barrier() moves it 2.9 %
        self.start()
        alias = self.host.alias(GROUP, NODE, "hub0.dim16.0", "dim16")
        self.rig.ctl("set dim16:0 0x0005")
        self.barrier(self.rig, "acm3p/")
        mark = self.host.mark()
        self.rig.ctl("set dim16:0 0x0105")  # in/8 on
        ddata = self.host.wait_message("DDATA", "hub0.dim16.0", since=mark)
        self.assertEqual(ddata.resolved, {"dim16/in/8": True, "dim16/word": 0x0105})
        instance = self.instance_of(ddata)
        self.assertEqual((instance.name, instance.alias, instance.datatype), (None, alias, None),
                         "by alias alone, the datatype left to the birth")
        self.assertEqual((instance.template.ref, instance.template.is_definition),
                         ("dim16", False))
        self.assertEqual([(m.name, m.alias, m.datatype) for m in instance.template.members],
                         [("in/8", None, None), ("word", None, None)])
        # deadband 1.0 (%) as gateway.md §5.5 says: a noisy channel publishes no member at all
        self.rig.ctl("set acm3p:0 1000 2000 100")
        self.barrier(self.rig, "acm3p/")
        mark = self.host.mark()
        for noisy in (2030, 1980, 2400, 2010):  # within ±0.61 %
            self.rig.ctl(f"set acm3p:0 1000 {noisy} 100")
            self.barrier(self.rig, "acm3p/")
        self.assertEqual([m.resolved for m in self.host.since(mark, "DDATA", "hub0.acm3p.0")
                          if {"acm3p/raw/1", "acm3p/value/1"} & m.resolved.keys()], [])
        mark = self.host.mark()
        self.rig.ctl("set acm3p:0 1000 2700 100")  # +1.07 %: raw/1 and value/1 together
        ddata = self.host.wait_metric("hub0.acm3p.0", "acm3p/raw/1", 2700, since=mark)
        self.assertEqual(sorted(ddata.resolved), ["acm3p/raw/1", "acm3p/value/1"])
        self.assertAlmostEqual(ddata.resolved["acm3p/value/1"], 2700 / 65535 * 100, places=4)

    def instance_command(self, device, instance, members, template_ref=None):
        """A DCMD payload of one instance with (name, datatype, value) members, for a raw
        publish."""
        payload = pb.Payload(timestamp=int(time.time() * 1000))
        m = payload.metrics.add(name=instance, datatype=19)
        m.template_value.template_ref = template_ref or instance
        m.template_value.is_definition = False
        for name, datatype, value in members:
            encode_value(m.template_value.metrics.add(name=name), datatype, value)
        return payload.SerializeToString()

    @covers("gateway.md §7.2")
    def test_dcmd_writes_an_instance_member_and_flat_names(self):
        self.start()
        self.assertEqual(int(self.rig.ctl("get dom16:0")) & 0x0088, 0)
        # as Ignition's MQTT Engine writes a UDT member: the instance holding that member
        mark, log = self.host.mark(), self.rig.log_mark()
        self.host.dcmd_instance(GROUP, NODE, "hub0.dom16.0", "dom16", {"out/3": True})
        ddata = self.host.wait_metric("hub0.dom16.0", "dom16/out/3", True, since=mark)
        self.assertEqual(ddata.resolved["dom16/word"] & 0x0008, 0x0008)
        self.assertEqual(int(self.rig.ctl("get dom16:0")) & 0x0008, 0x0008)
        self.rig.wait_log(r"DCMD hub0\.dom16\.0/dom16/out/3 = true: ", since=log)  # audited
        # by the instance's alias, two members at once
        alias = self.host.alias(GROUP, NODE, "hub0.dom16.0", "dom16")
        mark = self.host.mark()
        self.host.dcmd_instance(GROUP, NODE, "hub0.dom16.0", "dom16",
                                {"out/3": False, "out/7": True}, alias=alias)
        self.host.wait(lambda: self.value("hub0.dom16.0", "dom16/out/3") is False and
                       self.value("hub0.dom16.0", "dom16/out/7") is True, 5, "out/3 and out/7")
        # the flat §5.5 names are accepted as well
        mark = self.host.mark()
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0",
                       [{"name": "out/7", "value": False, "datatype": "Boolean"}])
        self.host.wait_metric("hub0.dom16.0", "dom16/out/7", False, since=mark)
        self.assertEqual(int(self.rig.ctl("get dom16:0")) & 0x0088, 0)
        # refused, each logged and nothing written: 18 members to a dom16 (17 writable), a
        # colour out of range, another type's instance, an input module's member
        log = self.rig.log_mark()
        self.host.publish_raw(dcmd_topic("hub0.dom16.0"), self.instance_command(
            "hub0.dom16.0", "dom16", [("out/0", "Boolean", True)] * 18))
        self.host.publish_raw(dcmd_topic("hub0.rgbdm.0"), self.instance_command(
            "hub0.rgbdm.0", "rgbdm", [("colour", "UInt8", 8)]))
        self.host.publish_raw(dcmd_topic("hub0.rgbdm.0"), self.instance_command(
            "hub0.rgbdm.0", "rgbdm", [("colour", "UInt8", 2)], template_ref="mux8m"))
        self.host.publish_raw(dcmd_topic("hub0.dim16.0"), self.instance_command(
            "hub0.dim16.0", "dim16", [("in/0", "Boolean", True)]))
        self.rig.wait_log(r"Sparkplug DCMD to hub0\.dom16\.0 refused: refused whole: it names "
                          r"18 metrics, and the device has 17 writable", since=log)
        self.rig.wait_log(r"DCMD hub0\.rgbdm\.0/rgbdm/colour = 8 refused", since=log)
        self.rig.wait_log(r"DCMD to hub0\.rgbdm\.0 refused: metric rgbdm: template_ref mux8m "
                          r"is not rgbdm", since=log)
        self.rig.wait_log(r"Sparkplug DCMD to hub0\.dim16\.0 refused: refused whole: it names 1 "
                          r"metrics, and the device has 0 writable", since=log)
        colour = 5 if self.rig.ctl("get rgbdm:0") != "5" else 6
        mark = self.host.mark()
        self.host.dcmd_instance(GROUP, NODE, "hub0.rgbdm.0", "rgbdm", {"colour": colour})
        self.host.wait_metric("hub0.rgbdm.0", "rgbdm/colour", colour, since=mark)
        self.assertEqual([m.resolved for m in self.host.since(mark, "DDATA", "hub0.rgbdm.0")],
                         [{"rgbdm/colour": colour}], "a refused command was applied")
        self.assertEqual(int(self.rig.ctl("get dom16:0")) & 0x0001, 0)
        self.assertEqual(self.rig.ctl("get rgbdm:0"), str(colour))

    @covers("gateway.md §7.2")
    def test_a_reload_that_changes_the_set_of_types_rebirths(self):
        nbirth = self.start()
        bdseq = nbirth.metric("bdSeq").value
        self.rig.configure(HUB_MODULES + ["mux8m:0"], mqtt_extra=self.EXTRA)
        mark, log = self.host.mark(), self.rig.log_mark()
        self.rig.daemon.send_signal(signal.SIGHUP)
        self.rig.wait_log(r"Sparkplug: the module map and its template types changed; new "
                          r"births", since=log)
        again = self.wait_births(mark, devices=list(METRICS))
        self.assertEqual(again.metric("bdSeq").value, bdseq, "the same session")
        self.assertEqual(self.host.since(mark, "NDEATH"), [])
        self.assertIn("_types_/mux8m", self.definitions(again))
        mux = self.instance_of(self.host.since(again.index, "DBIRTH", "hub0.mux8m.0")[0])
        self.assertEqual([(m.name, m.datatype) for m in mux.template.members],
                         [("pos", 5), ("neg", 5)])
        mark = self.host.mark()
        self.host.dcmd_instance(GROUP, NODE, "hub0.mux8m.0", "mux8m", {"pos": 3})
        self.host.wait_metric("hub0.mux8m.0", "mux8m/pos", 3, since=mark)
        self.assertEqual(int(self.rig.ctl("get mux8m:0")) >> 8, 3)
        # one type fewer: its definition goes with it
        self.rig.configure(["dim16:0", "dom16:0", "acm3p:0"], mqtt_extra=self.EXTRA)
        mark, log = self.host.mark(), self.rig.log_mark()
        self.rig.daemon.send_signal(signal.SIGHUP)
        self.rig.wait_log(r"the module map and its template types changed", since=log)
        again = self.wait_births(mark, devices=["hub0.dim16.0", "hub0.dom16.0", "hub0.acm3p.0",
                                                "press.id2"])
        self.assertEqual(sorted(self.definitions(again)),
                         ["_types_/acm3p", "_types_/dim16", "_types_/dom16", "_types_/id2"])
        # templates off again: a new session (NDEATH, the next bdSeq), flat as §5.5
        self.rig.configure(["dim16:0", "dom16:0", "acm3p:0"], mqtt_extra="  deadband: 1.0\n")
        mark = self.host.mark()
        self.rig.daemon.send_signal(signal.SIGHUP)
        flat = self.host.wait_message("NBIRTH", since=mark, node=NODE, timeout=10)
        # the old session's end: its NDEATH and, in MQTT 5, the will its DISCONNECT asked for
        self.assertEqual([m.metric("bdSeq").value for m in self.host.since(mark, "NDEATH")],
                         [bdseq, bdseq])
        self.assertEqual(flat.metric("bdSeq").value, (bdseq + 1) % 256)
        self.assertEqual(self.definitions(flat), {})
        dim = self.host.wait_message("DBIRTH", "hub0.dim16.0", since=flat.index, timeout=10)
        self.assertEqual([m.name for m in dim.metrics], [n for n, _ in METRICS["hub0.dim16.0"]])

    def test_the_template_rules_find_each_break(self):
        """The host app's template rules on canned messages of another node: each must catch
        what it claims to check, or the ids it covers are not checked."""
        now = int(time.time() * 1000)

        def payload(seq):
            return pb.Payload(timestamp=now, seq=seq)

        def template(p, name, is_definition, ref=None, members=(), alias=None):
            m = p.metrics.add(name=name, timestamp=now, datatype=19)
            if alias is not None:
                m.alias = alias
            if is_definition is not None:
                m.template_value.is_definition = is_definition
            if ref is not None:
                m.template_value.template_ref = ref
            for member, value in members:
                encode_value(m.template_value.metrics.add(name=member), "Boolean", value)
            if not members:
                m.template_value.version = "1"
            return m

        nbirth = payload(0)
        for name, datatype, value in (("bdSeq", "Int64", 0),
                                      ("Node Control/Rebirth", "Boolean", False)):
            encode_value(nbirth.metrics.add(name=name, timestamp=now), datatype, value)
        template(nbirth, "_types_/t", True, members=[("a", None), ("b", None)])
        template(nbirth, "_types_/refd", True, ref="t")  # a definition with a template_ref
        dbirth = payload(1)
        template(dbirth, "missing", False, "t", [("a", True)], alias=1)  # b missing in a birth
        template(dbirth, "nowhere", False, "u", [("a", True)], alias=2)  # no definition u
        template(dbirth, "unsaid", None, "t", [("a", True), ("b", True)], alias=3)
        ddata = payload(2)
        template(ddata, "_types_/late", True, members=[("a", None)])  # a definition in DDATA
        m = template(ddata, None, False, "t", [("c", True)])  # c is no member of t
        m.ClearField("name")
        m.alias = 1
        before = len(self.host.violations)
        with self.host._cond:
            for type_, p, device in (("NBIRTH", nbirth, ""), ("DBIRTH", dbirth, "/d"),
                                     ("DDATA", ddata, "/d")):
                self.host._receive(f"spBv1.0/canned/{type_}/rules{device}", p.SerializeToString())
        new, self.host.violations[before:] = self.host.violations[before:], []
        definitions = [v for v in new if v.startswith("[template definitions]")]
        instances = [v for v in new if v.startswith("[template instances]")]
        for text in ("_types_/refd: a definition with template_ref", "_types_/late: a "
                     "definition in DDATA"):
            self.assertTrue(any(text in v for v in definitions), (text, new))
        for text in ("missing: in a birth, members", "nowhere: template_ref u is no definition",
                     "unsaid: a Template without is_definition", "alias 1: members ['c'] are "
                     "not in t"):
            self.assertTrue(any(text in v for v in instances), (text, new))


class FromOutside(OwnDaemon):
    """Issue 37: what a neighbour on the broker or on the box can send or plant, each as it was
    reproduced against the tree before the fix (which failed these tests). The daemon runs in a
    memory cgroup of the unit's MemoryMax=256M where this machine gives one."""

    def setUp(self):
        self.store = os.path.join(tempfile.mkdtemp(dir=self.dir), "sparkplug")
        self.store_line = f"  store: {{ path: {self.store} }}\n"
        self.rig = self.new_rig(mqtt_extra="  primary_host_id: scada\n" + self.store_line)
        self.limit = MemoryLimit(256 << 20)

    def tearDown(self):
        self.host.publish_raw("spBv1.0/STATE/scada", b"", retain=True)  # no STATE for the next
        super().tearDown()
        self.limit.close()

    def start_online(self):
        mark = self.host.mark()
        self.rig.start_daemon()
        self.limit.add(self.rig.daemon.pid)
        self.host.state("scada", True)
        return self.wait_births(mark)

    def host_states(self):
        metrics = self.rig.metrics()
        return {result: int(re.search(
            rf'^ioportd_sparkplug_host_states_total{{result="{result}"}} (\d+)$', metrics,
            re.M).group(1)) for result in ("taken", "ahead", "stale", "refused")}

    def test_states_larger_than_a_state_are_refused_unread(self):
        # Before: each went whole to YAML::Load on the loop (these 300: 6.1 s of CPU; one of 2 MB:
        # OOM-killed under MemoryMax=256M, at every start if it was retained).
        self.start_online()
        pid = self.rig.daemon.pid
        rss, cpu = peak_rss(pid), cpu_seconds(pid)
        pad = [1] * (20 << 10)  # 60 KiB of JSON, a node each to a YAML reader
        for _ in range(300):
            self.host.publish_raw("spBv1.0/STATE/scada", json.dumps(
                {"online": True, "timestamp": int(time.time() * 1000), "pad": pad}))
        self.host.state("scada", True, retain=False)  # after them: the broker keeps the order
        eventually(lambda: self.host_states()["taken"] == 2, 20, lambda: self.host_states())
        self.assertEqual(self.host_states()["refused"], 300)
        cpu, grown = cpu_seconds(pid) - cpu, peak_rss(pid) - rss
        print(f"\n300 STATEs of 60 KiB: {cpu:.2f} s of ioportd's CPU, peak RSS "
              f"{grown / 1048576:+.1f} MiB", file=sys.stderr)
        if RSS_TELLS:
            self.assertLess(grown, 32 << 20)
        self.rig.wait_log(r"STATE of scada refused: \d+ bytes, more than the 1024 a STATE "
                          r"may have \(logged once a minute")
        client = self.modbus(self.rig)
        self.assertModbusAnswers(client)
        client.close()

    def test_a_huge_command_never_reaches_the_daemon(self):
        # Before: MQTT 3.1.1, and libmosquitto read a 64 MiB DCMD whole before decode_command
        # refused it (RSS from 15 to 146 MB; a larger one went past MemoryMax=256M). Now the
        # CONNECT says 64 KiB at most (MQTT 5), and Mosquitto drops what is larger for the node.
        self.huge_commands(refused=0)

    def test_a_huge_command_in_mqtt_3_1_1_is_refused_unread(self):
        # A broker that refuses MQTT 5 cannot be asked for a bound: it sends both whole, and the
        # relay under libmosquitto reads them in passing (gateway.md §7.5). Before: the same
        # 10.6 -> 138.5 MiB as with the test above before MQTT 5.
        front = Mqtt311Front(self.broker.port)
        front.start()
        self.addCleanup(front.close)
        self.rig.broker_url = f"mqtt://127.0.0.1:{front.port}"
        self.rig.configure(HUB_MODULES, "  primary_host_id: scada\n" + self.store_line)
        self.huge_commands(refused=2)
        self.rig.wait_log(r"mqtt: connected to \S+ as ioportd-plant1-box7 \(MQTT 3\.1\.1\)")
        for what in (r"DCMD to hub0\.dom16\.0", "NCMD"):
            self.rig.wait_log(rf"Sparkplug: {what} refused unread: 6710\d{{4}} bytes, more than "
                              r"the 65536 a message to this node may have")

    def huge_commands(self, refused):
        self.start_online()
        pid = self.rig.daemon.pid
        rss = peak_rss(pid)
        huge = pb.Payload(timestamp=int(time.time() * 1000))
        encode_value(huge.metrics.add(name="out/0"), "String", "1" * (64 << 20))
        huge = huge.SerializeToString()
        attacker = RawClient(self.broker.port, "hostile", 10 * SLOWDOWN)
        try:
            attacker.publish(dcmd_topic("hub0.dom16.0"), huge, 60 * SLOWDOWN)
            attacker.publish(f"spBv1.0/{GROUP}/NCMD/{NODE}", huge, 60 * SLOWDOWN)
        finally:
            attacker.close()
        huge = None
        # The node still serves: a DCMD after them acts. Mosquitto reads each whole before it
        # serves anyone else, which on a loaded machine can hold it past the node's keepalive
        # (5 s here): the node connects again, and a DCMD sent before it has subscribed again is
        # gone with its clean session. So the DCMD is sent until it acts.
        sent = [float("-inf")]

        def out5_set():
            if time.monotonic() - sent[0] >= 1:
                self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"name": "out/5", "value": True}])
                sent[0] = time.monotonic()
            return int(self.rig.ctl("get dom16:0"), 0) & 0x0020
        eventually(out5_set, 20, lambda: f"out/5 on; ioportd's log:\n{self.rig.log_text()[-3000:]}",
                   interval=0.2)
        self.assertIsNone(self.rig.daemon.poll(), "ioportd is running")
        peak = peak_rss(pid)
        grown = peak - rss
        print(f"\na 64 MiB DCMD and NCMD: peak RSS {rss / 1048576:.1f} -> {peak / 1048576:.1f} "
              f"MiB ({grown / 1048576:+.1f})", file=sys.stderr)
        if RSS_TELLS:
            self.assertLess(grown, 4 << 20)
        self.assertEqual(int(self.rig.ctl("get dom16:0"), 0) & 0x0001, 0, "out/0 never written")
        client = self.modbus(self.rig)
        self.assertModbusAnswers(client)
        client.close()
        # Had either come to the MQTT 5 node, it would have been refused, and counted.
        self.assertRegex(self.rig.metrics(),
                         rf'(?m)^ioportd_sparkplug_commands_total\{{result="refused"\}} {refused}$')

    def test_a_forged_timestamp_does_not_hide_the_host_going_offline(self):
        # Before: every genuine STATE after this one was "older", the host's real offline was
        # ignored, and the node published live into a host that was down, storing nothing.
        self.start_online()
        self.host.state("scada", True, retain=False, timestamp=2**64 - 1)
        self.rig.wait_log(r"STATE of scada is \d+ s ahead of this node's clock \(more than "
                          r"10 s\): taken as online, but not used to judge later STATEs")
        mark = self.host.mark()
        self.host.state("scada", False)  # the host's real offline, by its own clock
        self.host.wait_message("NDEATH", node=NODE, since=mark, timeout=10)
        self.rig.wait_log(r"the primary host scada is offline on this broker; NDEATH")
        eventually(lambda: not self.rig.state()["sparkplug"]["online"], 10, "the session over")
        self.rig.ctl("set dim16:0 0x0F0F")
        eventually(lambda: self.rig.state()["sparkplug"]["store"]["records"] >= 1, 10,
                   lambda: f"the change in the store: {self.rig.state()['sparkplug']}")
        self.assertEqual(self.host_states()["ahead"], 1)
        # Back online, by its clock: the history arrives.
        mark = self.host.mark()
        self.host.state("scada", True)
        self.wait_births(mark)
        eventually(lambda: any(name == "word" and value == 0x0F0F
                               for m in self.host.since(mark, "DDATA", "hub0.dim16.0")
                               for name, value, _ in m.historical), 20, "the stored change")

    def test_a_store_directory_others_can_write_is_refused(self):
        # Before: any existing directory was used, and links planted in one under a 1777
        # directory made a root-run ioportd truncate and overwrite the files they named.
        shared = os.path.join(self.dir, "shared")
        os.makedirs(shared, exist_ok=True)
        os.chmod(shared, 0o1777)
        self.rig.configure(HUB_MODULES, f"  store: {{ path: {shared} }}\n")
        run = subprocess.run([IOPORTD, "--config", self.rig.config], capture_output=True,
                             text=True, timeout=30)
        self.assertEqual(run.returncode, 1, run.stderr)
        self.assertIn(f"mqtt.store.path: {shared} is writable by others (mode 1777)", run.stderr)
        # A reload to it changes nothing.
        self.rig.configure(HUB_MODULES, self.store_line)
        self.start()
        self.rig.configure(HUB_MODULES, f"  store: {{ path: {shared} }}\n")
        mark = self.rig.log_mark()
        self.rig.daemon.send_signal(signal.SIGHUP)
        self.rig.wait_log(r"SIGHUP: mqtt\.store\.path: \S+ is writable by others \(mode 1777\).*"
                          r"the running configuration is kept", 10, mark)
        self.assertTrue(self.rig.state()["sparkplug"]["online"])
        self.assertEqual(os.listdir(shared), [])

    def test_the_store_is_scanned_off_the_loop(self):
        # Before: the scan ran before start-up finished and inside a reload (a 256 MiB store
        # stalled Modbus for 1.18 s); now "started" and "reloaded" come first, the scan's line
        # after them (benchmark 7g measures it at the largest max_size).
        self.rig.configure(HUB_MODULES, self.store_line)
        self.start()
        log = self.rig.log_text()
        started = re.search(r"ioportd \S+ started", log).start()
        scanned = self.rig.wait_log(r"Sparkplug store \S+: 0 record\(s\) to forward")
        self.assertLess(started, scanned.start())
        mark = self.rig.log_mark()
        self.rig.configure(HUB_MODULES, self.store_line + "  deadband: 0.5\n")
        self.rig.daemon.send_signal(signal.SIGHUP)
        reloaded = self.rig.wait_log(r"SIGHUP: reloaded", 10, mark)
        scanned = self.rig.wait_log(r"Sparkplug store \S+: \d+ record\(s\) to forward", 10,
                                    mark)
        self.assertLess(reloaded.start(), scanned.start())


class BrokerLogRules(unittest.TestCase):
    """BrokerLog on lines as mosquitto 2.0.11 writes them (`log_type all`): it finds what it
    is there to find."""

    GOOD = [
        "1: New client connected from 127.0.0.1:5 as ioportd-plant1-box7 (p2, c1, k5).",
        "1: Will message specified (20 bytes) (r0, q1).",
        "1: \tspBv1.0/plant1/NDEATH/box7",
        "1: Sending CONNACK to ioportd-plant1-box7 (0, 0)",
        "1: Received SUBSCRIBE from ioportd-plant1-box7",
        "1: \tspBv1.0/plant1/NCMD/box7 (QoS 1)",
        "1: ioportd-plant1-box7 1 spBv1.0/plant1/NCMD/box7",
        "1: \tspBv1.0/plant1/DCMD/box7/+ (QoS 1)",
        "1: ioportd-plant1-box7 1 spBv1.0/plant1/DCMD/box7/+",
        "1: Sending SUBACK to ioportd-plant1-box7",
        "1: Received PUBLISH from ioportd-plant1-box7 (d0, q0, r0, m0, "
        "'spBv1.0/plant1/NBIRTH/box7', ... (120 bytes))",
        "1: Received PUBLISH from ioportd-plant1-box7 (d0, q1, r0, m3, "
        "'spBv1.0/plant1/NDEATH/box7', ... (20 bytes))",
        "1: Received DISCONNECT from ioportd-plant1-box7",
        "1: Client ioportd-plant1-box7 disconnected.",
    ]

    def found(self, lines, primary_host=None):
        path = os.path.join(tempfile.mkdtemp(prefix="ioportd-log-"), "mosquitto.log")
        try:
            with open(path, "w") as f:
                f.write("\n".join(lines) + "\n")
            log = BrokerLog(path, CLIENT_ID, GROUP, NODE, primary_host)
            return log.check(), log
        finally:
            shutil.rmtree(os.path.dirname(path))

    def changed(self, index, line, primary_host=None):
        lines = list(self.GOOD)
        lines[index] = line
        return [v.split("]")[0] + "]" for v in self.found(lines, primary_host)[0]]

    def test_a_good_session_passes(self):
        found, log = self.found(self.GOOD)
        self.assertEqual(found, [])
        self.assertEqual((log.connects, log.publishes), (1, 2))

    def test_every_broken_rule_is_found(self):
        self.assertEqual(self.changed(0, self.GOOD[0].replace("c1", "c0")), ["[connect]"])
        self.assertEqual(self.changed(0, self.GOOD[0].replace("p2", "p1")), ["[connect]"])
        self.assertEqual(self.changed(0, self.GOOD[0].replace("p2", "p5")), [])  # MQTT 5
        self.assertEqual(self.changed(1, self.GOOD[1].replace("r0", "r1")), ["[will]"])
        self.assertEqual(self.changed(1, self.GOOD[1].replace("q1", "q0")), ["[will]"])
        self.assertEqual(self.changed(2, "1: \tspBv1.0/plant1/NDEATH/other"), ["[will]"])
        self.assertEqual(self.changed(5, "1: \tspBv1.0/plant1/NCMD/box7 (QoS 0)"),
                         ["[subscriptions]"])
        self.assertEqual(self.changed(7, "1: \tspBv1.0/plant1/DCMD/box7/x (QoS 1)"),
                         ["[subscriptions]"])
        self.assertEqual(self.changed(10, self.GOOD[10].replace("r0", "r1")), ["[publish flags]"])
        self.assertEqual(self.changed(10, self.GOOD[10].replace("q0", "q1")), ["[publish flags]"])
        self.assertEqual(self.changed(11, self.GOOD[11].replace("q1", "q0")), ["[publish flags]"])
        # with a primary host, its STATE subscription before the births
        self.assertEqual(self.changed(3, self.GOOD[3], primary_host="scada"), ["[subscriptions]"])
        # a publish after the client's end
        lines = self.GOOD + [self.GOOD[10]]
        self.assertEqual([v.split("]")[0] + "]" for v in self.found(lines)[0]],
                         ["[publish flags]"])


def broker_connections(pid, ports):
    """How many established TCP connections process `pid` has to any of `ports`: its socket
    inodes (/proc/PID/fd) against /proc/net/tcp."""
    inodes = set()
    fds = f"/proc/{pid}/fd"
    for fd in os.listdir(fds):
        try:
            target = os.readlink(os.path.join(fds, fd))
        except OSError:  # closed meanwhile
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    n = 0
    with open("/proc/net/tcp") as table:
        next(table)
        for row in table:
            fields = row.split()
            remote_port = int(fields[2].split(":")[1], 16)
            if fields[3] == "01" and fields[9] in inodes and remote_port in ports:
                n += 1
    return n


class TwoBrokers(unittest.TestCase):
    """gateway.md §6.2 (issue 26): `brokers` walked in order when one goes away; with a primary
    host, a broker without its STATE online is left (NDEATH first), and NCMD Node Control/Next
    Server walks too. Two real mosquitto instances, a host application on each."""

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="ioportd-spb2-")
        self.brokers = [Broker(tempfile.mkdtemp(dir=self.dir)) for _ in range(2)]
        for broker in self.brokers:
            broker.start()
        self.hosts = [HostApp(broker.port, client_id=f"ioportd-test-host-{i}")
                      for i, broker in enumerate(self.brokers)]
        self.rig = None
        self.logs = []

    def tearDown(self):
        if self.rig:
            self.rig.close()
        for host in self.hosts:
            host.close()
        for broker in self.brokers:
            broker.stop()
        at_brokers = [log.check() for log in self.logs]
        shutil.rmtree(self.dir, ignore_errors=True)
        for i, host in enumerate(self.hosts):
            self.assertEqual(host.violations, [], f"Sparkplug rules broken on broker {i}")
        for i, found in enumerate(at_brokers):
            self.assertEqual(found, [], f"Sparkplug rules broken at broker {i}")

    def start(self, mqtt_extra="", primary_host=None):
        if primary_host:
            mqtt_extra += f"  primary_host_id: {primary_host}\n"
        self.logs = [BrokerLog(b.log, CLIENT_ID, GROUP, NODE, primary_host) for b in self.brokers]
        self.rig = EdgeNodeRig(tempfile.mkdtemp(dir=self.dir), None, mqtt_extra=mqtt_extra,
                               broker_ports=[b.port for b in self.brokers])
        self.rig.start_daemon()

    def assert_one_broker(self):
        """Sparkplug 3.0 §7.1: connected to one MQTT server at a time, also right after a walk."""
        ports = {b.port for b in self.brokers}
        self.assertEqual(broker_connections(self.rig.daemon.pid, ports), 1,
                         "connections to the brokers at once")

    def broker_of_state(self):
        return self.rig.state()["sparkplug"]["broker"]

    @covers("tck-id-operational-behavior-primary-application-state-with-multiple-servers-single-server")
    def test_a_lost_broker_is_walked_past_to_the_next(self):
        self.start()
        self.hosts[0].wait_message("NBIRTH", node=NODE, timeout=10)
        mark = self.hosts[1].mark()
        self.brokers[0].stop()
        self.hosts[1].wait_message("NBIRTH", node=NODE, since=mark, timeout=15)
        self.assert_one_broker()
        self.assertEqual(self.broker_of_state(), f"mqtt://127.0.0.1:{self.brokers[1].port}")
        self.rig.wait_log(r"mqtt: connected to mqtt://127\.0\.0\.1:%d" % self.brokers[1].port)

    @covers("tck-id-operational-behavior-edge-node-birth-sequence-wait",
            "tck-id-operational-behavior-edge-node-termination-host-offline-reconnect",
            "tck-id-operational-behavior-primary-application-state-with-multiple-servers-walk",
            "tck-id-operational-behavior-primary-application-state-with-multiple-servers-state-subs",
            "tck-id-topics-ndeath-topic")
    def test_the_primary_host_decides_the_broker(self):
        # The host is online on broker 1 only: broker 0 sends no STATE within keepalive (5 s).
        self.hosts[1].state("scada", True)
        self.start(primary_host="scada")
        nbirth = self.hosts[1].wait_message("NBIRTH", node=NODE, timeout=20)
        self.assert_one_broker()
        self.assertEqual(self.hosts[0].since(0, "NBIRTH"), [], "no births where the host is not")
        self.rig.wait_log(r"no STATE of the primary host scada within 5 s; NDEATH, and leaving "
                          r"mqtt://127\.0\.0\.1:%d" % self.brokers[0].port)
        # The host asks for the next server: NDEATH on this broker, then the walk.
        mark = self.hosts[1].mark()
        self.hosts[1].ncmd_next_server(GROUP, NODE)
        death = self.hosts[1].wait_message("NDEATH", node=NODE, since=mark, timeout=10)
        self.assertEqual(death.metric("bdSeq").value, nbirth.metric("bdSeq").value)
        self.rig.wait_log(r"the host asked for the next server", 5)
        # Broker 0 still has no host: the node comes back to broker 1.
        self.hosts[1].wait_message("NBIRTH", node=NODE, since=mark, timeout=20)
        # The host going offline on this broker makes the node leave it too, for the next,
        # where the host is online now.
        mark, other = self.hosts[1].mark(), self.hosts[0].mark()
        self.hosts[0].state("scada", True)
        self.hosts[1].state("scada", False)
        self.hosts[1].wait_message("NDEATH", node=NODE, since=mark, timeout=10)
        self.rig.wait_log(r"the primary host scada is offline on this broker", 5)
        self.hosts[0].wait_message("NBIRTH", node=NODE, since=other, timeout=20)
        self.assert_one_broker()
        self.assertEqual(self.broker_of_state(), f"mqtt://127.0.0.1:{self.brokers[0].port}")


class SecureBroker(unittest.TestCase):
    """mqtts with a CA of the test's, a user and a password file: the edge node on a TLS
    listener that refuses anonymous clients; the host app on a plain listener of the same
    broker."""

    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="ioportd-spb-tls-")
        d = cls.dir

        def openssl(*args):
            subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)
        openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
                "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj", "/CN=test CA")
        openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
                "-keyout", "server.key", "-out", "server.csr", "-subj", "/CN=localhost")
        with open(os.path.join(d, "san.ext"), "w") as f:
            f.write("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
        openssl("x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                "-CAcreateserial", "-out", "server.pem", "-days", "2", "-extfile", "san.ext")
        subprocess.run(["mosquitto_passwd", "-b", "-c", os.path.join(d, "passwd"), "box7",
                        "s3cret"], check=True, capture_output=True)
        for name, secret in (("password", "s3cret\n"), ("wrong", "guess\n")):
            path = os.path.join(d, name)
            with open(path, "w") as f:
                f.write(secret)
            os.chmod(path, 0o640)
        # mosquitto started as root runs as the user mosquitto, which must read these
        os.chmod(d, 0o755)
        for name in ("ca.pem", "server.pem", "server.key", "passwd"):
            os.chmod(os.path.join(d, name), 0o644)
        cls.broker = Broker(d)
        cls.tls_port = free_port()
        with open(cls.broker.config, "w") as f:
            f.write(f"""per_listener_settings true
persistence false
listener {cls.broker.port} 127.0.0.1
allow_anonymous true
listener {cls.tls_port} 127.0.0.1
cafile {d}/ca.pem
certfile {d}/server.pem
keyfile {d}/server.key
allow_anonymous false
password_file {d}/passwd
""")
        cls.broker.start()
        cls.host = HostApp(cls.broker.port)

    @classmethod
    def tearDownClass(cls):
        cls.host.close()
        cls.broker.stop()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def test_mqtts_with_a_user_and_a_password_file(self):
        def mqtt_extra(password):
            return (f"  username: box7\n  password_file: {self.dir}/{password}\n"
                    f"  ca_file: {self.dir}/ca.pem\n")
        rig = EdgeNodeRig(tempfile.mkdtemp(dir=self.dir), self.broker.port,
                          mqtt_extra=mqtt_extra("wrong"),
                          broker_url=f"mqtts://127.0.0.1:{self.tls_port}")
        try:
            rig.start_daemon()
            # a wrong password: refused, said once, retried; Modbus as ever
            # "Not authorized" in MQTT 5's reason string, "not authorised" in 3.1.1's CONNACK
            rig.wait_log(r"refused the connection: .*[Nn]ot authori[sz]ed", 10)
            client = ModbusTcpClient("127.0.0.1", port=rig.port, timeout=3)
            assert client.connect()
            self.assertFalse(client.read_input_registers(1000, 1, slave=1).isError())
            client.close()
            # the right one, by SIGHUP: the new settings begin a session over TLS
            mark = self.host.mark()
            rig.configure(HUB_MODULES, mqtt_extra("password"))
            rig.daemon.send_signal(signal.SIGHUP)
            rig.wait_log(r"mqtt: connected to mqtts://127\.0\.0\.1:\d+ as ioportd-plant1-box7",
                         15)
            nbirth = self.host.wait_message("NBIRTH", since=mark, node=NODE, timeout=10)
            self.host.wait_message("DBIRTH", "hub0.dim16.0", since=nbirth.index, timeout=10)
            self.assertEqual(self.host.violations, [])
        finally:
            if rig.daemon and rig.daemon.poll() is None:
                rig.stop_daemon(signal.SIGTERM)
            rig.close()

    def tls_rig(self, mqtt_extra, url=None):
        rig = EdgeNodeRig(tempfile.mkdtemp(dir=self.dir), self.broker.port, mqtt_extra=mqtt_extra,
                          broker_url=url or f"mqtts://127.0.0.1:{self.tls_port}")
        self.addCleanup(rig.close)
        self.addCleanup(lambda: rig.daemon and rig.daemon.poll() is None
                        and rig.stop_daemon(signal.SIGTERM))
        return rig

    def test_mqtts_in_mqtt_3_1_1_through_the_relay(self):
        # MQTT 3.1.1: libmosquitto speaks to the relay on loopback, and the relay speaks TLS to
        # the broker, checking it as libmosquitto does (gateway.md §7.5).
        rig = self.tls_rig(f"  username: box7\n  password_file: {self.dir}/password\n"
                           f"  ca_file: {self.dir}/ca.pem\n  protocol: 3.1.1\n")
        mark = self.host.mark()
        rig.start_daemon()
        rig.wait_log(r"mqtt: connected to mqtts://127\.0\.0\.1:\d+ as ioportd-plant1-box7 "
                     r"\(MQTT 3\.1\.1\)", 15)
        nbirth = self.host.wait_message("NBIRTH", since=mark, node=NODE, timeout=10)
        self.host.wait_message("DBIRTH", "hub0.dom16.0", since=nbirth.index, timeout=10)
        # and the other way, a command from the host through the relay
        self.host.dcmd(GROUP, NODE, "hub0.dom16.0", [{"name": "out/2", "value": True}])
        eventually(lambda: int(rig.ctl("get dom16:0"), 0) & 0x0004, 10 * SLOWDOWN, "out/2 on")
        self.assertEqual(self.host.violations, [])

    def test_a_broker_the_ca_did_not_sign_is_refused_in_mqtt_3_1_1(self):
        # server.pem as the CA: it is not one, so the chain does not verify.
        rig = self.tls_rig(f"  username: box7\n  password_file: {self.dir}/password\n"
                           f"  ca_file: {self.dir}/server.pem\n  protocol: 3.1.1\n")
        rig.start_daemon()
        rig.wait_log(r"mqtt: mqtts://127\.0\.0\.1:\d+'s certificate is not accepted: [^;]*"
                     r"certificate[^;]*; ca_file must be the CA that signed it, for the name in "
                     r"the URL; reconnecting within 1 s", 15)
        self.assertNotIn("connected to", rig.log_text())

    def test_a_broker_that_never_answers_tls_is_given_up_after_the_keepalive(self):
        silent = socket.create_server(("127.0.0.1", 0))
        self.addCleanup(silent.close)
        rig = self.tls_rig(f"  ca_file: {self.dir}/ca.pem\n  protocol: 3.1.1\n",
                           f"mqtts://127.0.0.1:{silent.getsockname()[1]}")
        started = time.monotonic()
        rig.start_daemon()
        rig.wait_log(r"mqtt: no TLS handshake with mqtts://127\.0\.0\.1:\d+ within 5 s; "
                     r"reconnecting within 1 s", 15 * SLOWDOWN)
        # libmosquitto counts the keepalive in whole seconds, and may end the attempt up to one
        # early; the relay's own deadline is the keepalive to the millisecond.
        self.assertGreater(time.monotonic() - started, 4, "not before the keepalive")


if __name__ == "__main__":
    # Test names may follow the three paths, e.g. Lifecycle.test_sighup.
    unittest.main(argv=sys.argv[:1] + sys.argv[4:], verbosity=2)
