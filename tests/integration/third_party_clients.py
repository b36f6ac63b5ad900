#!/usr/bin/python3
"""ioportd through Modbus clients that are not ours: pymodbus (python3-pymodbus) and mbpoll,
both from Debian, against the real daemon and the real simulator on ptys.

FC 23 and FC 43/14 go through pymodbus alone: mbpoll has neither (its -u is FC 17, RTU only).

Usage: third_party_clients.py IOPORTD IOPORT_SIM
"""
import os
import re
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import unittest

IOPORTD, IOPORT_SIM = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))

from rig import SLOWDOWN, Rig, eventually  # noqa: E402
from pymodbus.client import ModbusTcpClient  # noqa: E402
from pymodbus.constants import DeviceInformation  # noqa: E402
from pymodbus.mei_message import ReadDeviceInformationRequest  # noqa: E402


def config(rig):
    return f"""modbus:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {rig.hub_link}
    unit_id: 1
    timeout: 300ms
    modules:
      - {{ type: dim16, number: 0 }}
      - {{ type: dom16, number: 0 }}
      - {{ type: acm3p, number: 0, channels: {{ 0: {{ unit: "°C", scale: [0, 100, -20, 150] }} }} }}
      - {{ type: rgbdm, number: 0 }}
  - name: press
    protocol: id2
    device: {rig.id2_link}
    unit_id: 2
"""


def float32(value):
    """`value` rounded to single precision, as a float32 register holds it."""
    return struct.unpack(">f", struct.pack(">f", value))[0]


class ThirdPartyClients(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        """ioport-sim with a hub (unit 1) and one with an ID-2 (unit 2), and ioportd on them, in
        a temporary directory."""
        cls.dir = tempfile.mkdtemp(prefix="ioportd-3p-")
        cls.rig = Rig(cls.dir, IOPORTD, IOPORT_SIM)
        cls.client = None
        try:
            cls.rig.start_hub("dim16:0,dom16:0,acm3p:0,rgbdm:0")
            cls.rig.start_id2()
            cls.rig.write_config(config(cls.rig))
            cls.rig.start_daemon()
            cls.port = cls.rig.listening_port("Modbus TCP")
            cls.client = ModbusTcpClient("127.0.0.1", port=cls.port, timeout=3 * SLOWDOWN)
            assert cls.client.connect()

            def online():
                r = cls.client.read_input_registers(1000, 1, slave=1)
                return not r.isError() and r.registers[0] == 1
            eventually(online, 5, lambda: "hub0 online:\n" + cls.rig.log_text())
        except BaseException:
            cls.close()
            raise

    @classmethod
    def tearDownClass(cls):
        code, log = cls.close()
        assert code == 0, f"ioportd exited {code} on SIGTERM:\n{log}"

    @classmethod
    def close(cls):
        """Everything stopped and removed; ioportd's exit status on SIGTERM (None if it never
        started) and its log."""
        code = log = None
        try:
            if cls.client:
                cls.client.close()
            if cls.rig.daemon:
                code = cls.rig.stop_daemon(timeout=5)[1]
                log = cls.rig.log_text()
        finally:
            cls.rig.close()
            shutil.rmtree(cls.dir, ignore_errors=True)
        return code, log

    def mbpoll(self, *args):
        out = subprocess.run(["mbpoll", "-1", "-m", "tcp", "-p", str(self.port), *args],
                             capture_output=True, text=True, timeout=20 * SLOWDOWN)
        self.assertEqual(out.returncode, 0, out.stdout + out.stderr)
        return out.stdout

    def test_pymodbus_reads_inputs_and_floats(self):
        self.rig.ctl("set dim16:0 0x8001")
        self.rig.ctl("set acm3p:0 13208 41203 4095")

        def updated():
            r = self.client.read_input_registers(0, 1, slave=1)
            return not r.isError() and r.registers[0] == 0x8001
        eventually(updated, what="dim16 0 is 0x8001")
        bits = self.client.read_discrete_inputs(0, 16, slave=1)
        self.assertEqual(bits.bits[:16], [True] + [False] * 14 + [True])
        # Both channels: another test may have left channel 0 at 13208 already.
        eventually(lambda: self.client.read_input_registers(16, 2, slave=1).registers == [13208,
                                                                                        41203],
                   what="acm3p 0 channels 0 and 1 are 13208 and 41203")
        r = self.client.read_input_registers(200, 4, slave=1)
        values = struct.unpack(">ff", struct.pack(">HHHH", *r.registers))
        # Channel 0 is scaled (gateway.md §6.1): the double formula, rounded once to float32.
        self.assertEqual(values[0], float32(-20 + 13208 / 65535 * 100 * 170 / 100))
        self.assertEqual(values[1], float32(41203 / 65535 * 100))  # channel 1: percent

    def test_pymodbus_writes_coils_and_registers(self):
        self.assertFalse(self.client.write_register(0, 0x1234, slave=1).isError())
        self.assertEqual(self.rig.ctl("get dom16:0"), str(0x1234))
        self.assertFalse(self.client.write_coils(0, [False, True], slave=1).isError())
        self.assertEqual(self.rig.ctl("get dom16:0"), str(0x1236))
        self.assertFalse(self.client.write_registers(8, [4], slave=1).isError())
        self.assertEqual(self.rig.ctl("get rgbdm:0").split()[0], "4")

    def test_pymodbus_sees_the_exceptions(self):
        self.assertEqual(self.client.read_input_registers(0, 1, slave=9).exception_code, 0x0A)
        self.assertEqual(self.client.write_register(8, 9, slave=1).exception_code, 0x03)
        self.assertEqual(self.client.read_input_registers(80, 1, slave=1).exception_code, 0x02)
        self.assertEqual(self.client.write_register(9, 1, slave=1).exception_code, 0x02)

    def identify(self, unit, code, object_id=0x00):
        return self.client.execute(
            ReadDeviceInformationRequest(read_code=code, object_id=object_id, unit=unit))

    def test_pymodbus_reads_the_device_identification(self):
        out = subprocess.run([IOPORTD, "--version"], capture_output=True, text=True,
                             timeout=10 * SLOWDOWN)
        self.assertEqual(out.returncode, 0, out.stderr)
        version = re.fullmatch(r"ioportd (\S+)\n", out.stdout).group(1)
        for unit, model, name in ((1, "ioport hub", "hub0"), (2, "ID-2", "press")):
            objects = {0x00: "ioportd developers", 0x01: "ioportd", 0x02: version,
                       0x03: "man:ioportd(8)", 0x04: "ioportd serial-to-Modbus gateway",
                       0x05: model, 0x06: name}
            objects = {k: v.encode() for k, v in objects.items()}
            basic = {k: objects[k] for k in (0x00, 0x01, 0x02)}
            with self.subTest(unit=unit):
                # Stream access: basic (00-02), regular and extended (00-06, as there are no
                # extended objects), each whole in one response.
                for code, expected in ((DeviceInformation.Basic, basic),
                                       (DeviceInformation.Regular, objects),
                                       (DeviceInformation.Extended, objects)):
                    r = self.identify(unit, code)
                    self.assertFalse(r.isError(), r)
                    self.assertEqual(r.read_code, code)
                    self.assertEqual(r.conformity, 0x82)
                    self.assertEqual((r.more_follows, r.next_object_id), (0x00, 0x00))
                    self.assertEqual(r.number_of_objects, len(expected))
                    self.assertEqual(r.information, expected)
                # A stream from an object of its category starts there; from one that is not
                # (03 is regular), at 00.
                r = self.identify(unit, DeviceInformation.Regular, 0x04)
                self.assertEqual(r.information, {k: objects[k] for k in (0x04, 0x05, 0x06)})
                r = self.identify(unit, DeviceInformation.Basic, 0x03)
                self.assertEqual(r.information, basic)
                # Individual access: the one object, or 02 for an object there is not.
                for object_id in (0x02, 0x05, 0x06):
                    r = self.identify(unit, DeviceInformation.Specific, object_id)
                    self.assertFalse(r.isError(), r)
                    self.assertEqual((r.read_code, r.conformity, r.more_follows),
                                     (DeviceInformation.Specific, 0x82, 0x00))
                    self.assertEqual(r.information, {object_id: objects[object_id]})
                self.assertEqual(
                    self.identify(unit, DeviceInformation.Specific, 0x07).exception_code, 0x02)
                self.assertEqual(self.identify(unit, 5).exception_code, 0x03)

    def test_pymodbus_read_write_registers(self):
        # The write first, confirmed by the device, then the read: it sees the value written.
        r = self.client.readwrite_registers(read_address=0, read_count=1, write_address=0,
                                            write_registers=[0x5AA5], unit=1)
        self.assertFalse(r.isError(), r)
        self.assertEqual(self.rig.ctl("get dom16:0"), str(0x5AA5))
        self.assertEqual((r.function_code, r.registers), (0x17, [0x5AA5]))
        # Another range read than written: dom16 0 (0-7, 1-7 not configured) and rgbdm 0 (8).
        r = self.client.readwrite_registers(read_address=0, read_count=9, write_address=8,
                                            write_registers=[6], unit=1)
        self.assertFalse(r.isError(), r)
        self.assertEqual(self.rig.ctl("get rgbdm:0").split()[0], "6")
        self.assertEqual((r.function_code, r.registers), (0x17, [0x5AA5, 0, 0, 0, 0, 0, 0, 0, 6]))
        # Colour 9 does not exist: 03, nothing written, nothing read.
        r = self.client.readwrite_registers(read_address=0, read_count=9, write_address=8,
                                            write_registers=[9], unit=1)
        self.assertEqual((r.function_code, r.exception_code), (0x97, 0x03))
        self.assertEqual(self.rig.ctl("get rgbdm:0").split()[0], "6")
        self.assertEqual(self.client.read_holding_registers(8, 1, slave=1).registers, [6])

    def test_mbpoll_reads_and_writes(self):
        self.rig.ctl("set dim16:0 0x00F0")
        self.rig.ctl("set acm3p:0 13208 0 0")
        eventually(lambda: self.client.read_input_registers(0, 1, slave=1).registers[0] == 0x00F0,
                   what="dim16 0 is 0x00F0")
        eventually(lambda: self.client.read_input_registers(16, 1, slave=1).registers[0] == 13208,
                   what="acm3p 0 channel 0 is 13208")
        out = self.mbpoll("-a", "1", "-t", "3:hex", "-r", "1", "-c", "1", "127.0.0.1")
        self.assertRegex(out, r"\[1\]:\s+0x00F0")
        self.mbpoll("-a", "1", "-t", "4", "-r", "1", "127.0.0.1", "4660")
        self.assertEqual(self.rig.ctl("get dom16:0"), "4660")
        out = self.mbpoll("-a", "1", "-t", "3:float", "-B", "-r", "201", "-c", "1", "127.0.0.1")
        self.assertRegex(out, r"\[201\]:\s+14\.26")  # 20.15 % scaled to °C

    def test_malformed_frame_closes_only_its_own_connection(self):
        with socket.create_connection(("127.0.0.1", self.port), timeout=3 * SLOWDOWN) as bad:
            # transaction 1, protocol id 1 (must be 0), length 6, unit 1, FC04 0 1
            bad.sendall(bytes.fromhex("0001 0001 0006 01 04 0000 0001"))
            self.assertEqual(bad.recv(100), b"")  # closed, not answered
        r = self.client.read_input_registers(1000, 1, slave=1)
        self.assertFalse(r.isError())


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
