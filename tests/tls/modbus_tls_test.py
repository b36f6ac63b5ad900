#!/usr/bin/env python3
"""Modbus/TCP Security (gateway.md §5.6) against the real daemon on the simulators, with
certificates made here by openssl, as docs/tls.md tells a person to make them: a CA, a server
certificate, clients with the roles operator, viewer and line2 (unit 2 only), one with a role no
one configured, one without a role, one expired and one from another CA.

Clients: pymodbus's TLS client (Debian's python3-pymodbus, with the socket framer: the MBAP
header inside TLS, pymodbus #2014), raw Modbus frames over Python's ssl module where a test needs
the bytes, and openssl s_client for what the server offers.

Usage: modbus_tls_test.py IOPORTD IOPORT_SIM [unittest arguments]
"""

import asyncio
import os
import re
import select
import shutil
import socket
import ssl
import struct
import subprocess
import sys
import tempfile
import threading
import time
import unittest

IOPORTD, IOPORT_SIM = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))

from certificates import Certificates  # noqa: E402
from rig import Rig, eventually  # noqa: E402
from pymodbus.client import AsyncModbusTlsClient  # noqa: E402
from pymodbus.framer.socket_framer import ModbusSocketFramer  # noqa: E402

ILLEGAL_FUNCTION = 0x01
GATEWAY_PATH_UNAVAILABLE = 0x0A


def make_certificates(directory):
    """The CA and the server's certificate; clients with the roles operator, viewer, line2 (unit
    2 only) and admin (configured nowhere), one without a role, one of another CA, one expired."""
    certs = Certificates(directory)
    certs.ca("other-ca", "Some Other CA")
    for name in ("operator", "viewer", "line2", "admin"):
        certs.client(name, name)
    certs.client("norole", None)
    certs.client("foreign", "operator", ca="other-ca")
    certs.expired("expired", "operator")
    return certs


def config(rig, certs, plain="127.0.0.1:0", tls_extra="", server="server", max_connections=64,
           modbus_extra=""):
    """plain=None: no modbus.listen (with tls: no plain listener)."""
    listen = "" if plain is None else f'  listen: "{plain}"\n'
    return f"""modbus:
{listen}  max_connections: {max_connections}
{modbus_extra}  tls:
    listen: "127.0.0.1:0"
    certificate: {certs.path(server + '.pem')}
    key: {certs.path(server + '.key')}
    client_ca: {certs.path('ca.pem')}
{tls_extra}    roles:
      operator: {{ units: all, access: read_write }}
      viewer:   {{ units: all, access: read }}
      line2:    {{ units: [2], access: read_write }}
http:
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
  - name: press
    protocol: id2
    device: {rig.id2_link}
    unit_id: 2
    timeout: 300ms
"""


class TlsClient:
    """Raw Modbus frames over TLS: the MBAP ADU unchanged inside TLS (the specification)."""

    def __init__(self, port, context, timeout=5, receive_buffer=None, source="127.0.0.1"):
        raw = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if receive_buffer:  # set before connecting: the window it offers follows from it
            raw.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        raw.settimeout(timeout)
        raw.bind((source, 0))  # loopback is 127.0.0.0/8: one machine, many client addresses
        try:
            raw.connect(("127.0.0.1", port))
        except OSError:
            raw.close()
            raise
        self.socket = context.wrap_socket(raw, server_hostname="127.0.0.1")
        self.transaction = 0

    def request(self, unit, pdu):
        """The response PDU."""
        self.transaction = (self.transaction + 1) & 0xFFFF
        self.socket.sendall(struct.pack(">HHHB", self.transaction, 0, len(pdu) + 1, unit) + pdu)
        header = self.read(7)
        transaction, _, length, answered_unit = struct.unpack(">HHHB", header)
        assert (transaction, answered_unit) == (self.transaction, unit), header
        return self.read(length - 1)

    def read(self, n):
        data = b""
        while len(data) < n:
            chunk = self.socket.recv(n - len(data))
            if not chunk:
                raise ConnectionError("closed by the server")
            data += chunk
        return data

    def exception(self, unit, pdu):
        """The exception code of the response, or None for a normal response."""
        response = self.request(unit, pdu)
        return response[1] if response[0] & 0x80 else None

    def close(self):
        self.socket.close()


def read_pdu(function, address, count):
    return struct.pack(">BHH", function, address, count)


def plain_request(port, unit, pdu, timeout=5):
    """One request on a new plain Modbus TCP connection: the response PDU."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(struct.pack(">HHHB", 1, 0, len(pdu) + 1, unit) + pdu)
        data = b""
        while len(data) < 7 or len(data) < 6 + struct.unpack(">H", data[4:6])[0]:
            chunk = s.recv(512)
            if not chunk:
                raise ConnectionError(f"closed by the server after {data!r}")
            data += chunk
        return data[7:]


def silent(port, source):
    """A TCP connection to `port` from `source` that says nothing: None when refused."""
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.settimeout(2)
    try:
        s.bind((source, 0))
        s.connect(("127.0.0.1", port))
        return s
    except OSError:
        s.close()
        return None


def modules(rig):
    """The state API's modules of every link, by id ("dim16 0", "ID-2")."""
    return {m["module"]: m for link in rig.state()["links"] for m in link["modules"]}


def wait_online(rig, condition=None, deadline=10):
    """Until every module of every link is online by the state API (and `condition(modules)`
    holds): the precondition of a read that must be served. Units 1 and 2 answer reads from the
    image, 0B for a module not polled yet since the start, or offline since a transaction failed
    (under load a timeout) until its next poll succeeds."""
    def ready():
        found = modules(rig)
        return all(m["status_text"] == "online" for m in found.values()) and \
            (condition is None or condition(found))
    eventually(ready, deadline, lambda: f"every module online: {modules(rig)}")


WRITES = [struct.pack(">BHH", 0x05, 0, 0xFF00), struct.pack(">BHH", 0x06, 0, 0x0001),
          struct.pack(">BHHBB", 0x0F, 0, 1, 1, 1), struct.pack(">BHHBH", 0x10, 0, 1, 2, 1),
          struct.pack(">BHHHHBH", 0x17, 0, 1, 0, 1, 2, 1)]


def refused(port, context, payload=None, timeout=8):
    """What the server does with a client it must not serve: the handshake fails or the
    connection closes; a Modbus answer is never read. Returns what happened, in words."""
    raw = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    if payload is not None:  # not TLS at all
        raw.sendall(payload)
        data = raw.recv(1024)
        raw.close()
        assert not data.startswith(payload[:2]), f"a Modbus answer: {data!r}"
        return "closed" if data == b"" else f"{len(data)} bytes that are no Modbus answer"
    try:
        tls = context.wrap_socket(raw, server_hostname="127.0.0.1")
    except (ssl.SSLError, ConnectionError) as error:
        raw.close()
        return f"handshake failed: {error}"
    # TLS 1.3: the client's certificate is checked after the client's Finished; the refusal
    # arrives as the first read.
    try:
        tls.sendall(struct.pack(">HHHB", 1, 0, 6, 1) + read_pdu(0x03, 0, 1))
        data = tls.recv(1024)
    except (ssl.SSLError, ConnectionError) as error:
        return f"refused after the handshake: {error}"
    finally:
        tls.close()
    assert data == b"", f"a Modbus answer to a refused client: {data!r}"
    return "closed"


class ModbusTls(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="ioportd-tls-")
        cls.certs = make_certificates(cls.dir)
        cls.rig = Rig(cls.dir, IOPORTD, IOPORT_SIM)
        try:
            cls.rig.start_hub("dim16:0,dom16:0")
            cls.rig.start_id2()
            cls.rig.write_config(config(cls.rig, cls.certs))
            cls.rig.start_daemon()
            cls.port = cls.rig.listening_port("Modbus TCP")
            cls.tls_port = cls.rig.listening_port("Modbus/TCP Security (TLS)")
        except BaseException:
            cls.rig.close()
            raise

    @classmethod
    def tearDownClass(cls):
        cls.rig.close()
        shutil.rmtree(cls.dir, ignore_errors=True)

    def client(self, name, **versions):
        return TlsClient(self.tls_port, self.certs.context(name, **versions))

    def metric(self, line):
        text = self.rig.metrics()
        found = re.search("^" + re.escape(line) + r" (\d+)$", text, re.M)
        assert found, line
        return int(found.group(1))

    # --- Roles ---------------------------------------------------------------------------

    def test_pymodbus_with_the_operator_certificate_reads_and_writes(self):
        self.rig.ctl("set dim16:0 0x0005")
        # The set reaches the image with dim16 0's next poll: awaited before the read.
        wait_online(self.rig, lambda found: found["dim16 0"]["word"] == 0x0005)
        context = self.certs.context("operator")

        async def session():
            client = AsyncModbusTlsClient("127.0.0.1", port=self.tls_port, sslctx=context,
                                          framer=ModbusSocketFramer,
                                          server_hostname="127.0.0.1", timeout=5)
            await client.connect()
            self.assertTrue(client.connected)
            try:
                inputs = await client.read_discrete_inputs(0, 16, slave=1)
                written = await client.write_register(0, 0x0102, slave=1)
                coils = await client.read_coils(0, 16, slave=1)
                return inputs, written, coils
            finally:
                await client.close()

        inputs, written, coils = asyncio.run(session())
        self.assertFalse(inputs.isError(), inputs)
        self.assertEqual(inputs.bits[:4], [True, False, True, False])
        self.assertFalse(written.isError(), written)
        self.assertEqual(self.rig.ctl("get dom16:0"), str(0x0102))
        self.assertEqual(coils.bits[:9], [False, True] + [False] * 6 + [True])
        self.rig.wait_log(r"Modbus/TCP Security client 127\.0\.0\.1:\d+ \(O=Plant,CN=operator-1, "
                          r"TLS TLSv1\.3\): role operator from the certificate, read_write")

    def test_the_viewer_reads_and_gets_01_on_every_write(self):
        client = self.client("viewer")
        try:
            wait_online(self.rig)
            for function in (0x01, 0x02, 0x03, 0x04):
                self.assertIsNone(client.exception(1, read_pdu(function, 0, 1)), function)
            self.assertIsNone(client.exception(2, read_pdu(0x02, 0, 1)))
            for write in WRITES:
                self.assertEqual(client.exception(1, write), ILLEGAL_FUNCTION, write.hex())
            # Device identification is a read.
            self.assertIsNone(client.exception(1, bytes([0x2B, 0x0E, 0x01, 0x00])))
        finally:
            client.close()
        self.rig.wait_log(r"client 127\.0\.0\.1:\d+: FC 05 to unit 1 refused \(exception 01\): "
                          r"role viewer may only read \(logged once per connection\)")

    def test_a_certificate_without_a_role_gets_01_on_everything(self):
        client = self.client("norole")
        try:
            self.assertEqual(client.exception(1, read_pdu(0x03, 0, 1)), ILLEGAL_FUNCTION)
            self.assertEqual(client.exception(2, read_pdu(0x02, 0, 1)), ILLEGAL_FUNCTION)
            self.assertEqual(client.exception(1, WRITES[0]), ILLEGAL_FUNCTION)
            # An unknown unit is 0A first (gateway.md §4's precedence: 0A, then the role's 01).
            self.assertEqual(client.exception(9, read_pdu(0x03, 0, 1)), GATEWAY_PATH_UNAVAILABLE)
        finally:
            client.close()
        self.rig.wait_log(r"CN=norole-1, TLS TLSv1\.3\): no role in the certificate and no "
                          r"default_role: no rights")

    def test_a_role_no_one_configured_gets_nothing(self):
        client = self.client("admin")
        try:
            self.assertEqual(client.exception(1, read_pdu(0x01, 0, 1)), ILLEGAL_FUNCTION)
        finally:
            client.close()
        self.rig.wait_log(r"role admin from the certificate is not configured: no rights")

    def test_a_unit_outside_the_role_gets_01(self):
        client = self.client("line2")
        try:
            wait_online(self.rig)
            self.assertIsNone(client.exception(2, read_pdu(0x02, 0, 1)))
            self.assertIsNone(client.exception(2, struct.pack(">BHH", 0x05, 0, 0x0000)))
            self.assertEqual(client.exception(1, read_pdu(0x03, 0, 1)), ILLEGAL_FUNCTION)
            self.assertEqual(client.exception(1, WRITES[1]), ILLEGAL_FUNCTION)
        finally:
            client.close()

    def test_the_status_api_shows_tls_clients_with_their_role(self):
        client = self.client("viewer")
        try:
            client.request(1, read_pdu(0x03, 0, 1))
            modbus = self.rig.state()["modbus"]
            self.assertEqual(modbus["tls_listen"], f"127.0.0.1:{self.tls_port}")
            mine = [c for c in modbus["clients"] if c["transport"] == "tls"]
            self.assertEqual([c["role"] for c in mine], ["viewer"])
        finally:
            client.close()

    # --- Who is refused ------------------------------------------------------------------

    def assert_refused(self, context=None, payload=None, log=None):
        keeper = self.client("operator")  # served before, during and after
        try:
            before = self.metric('ioportd_modbus_connections_refused_total{reason="tls_handshake"}')
            started = time.monotonic()
            what = refused(self.tls_port, context, payload)
            self.assertLess(time.monotonic() - started, 2, what)
            wait_online(self.rig)
            self.assertIsNone(keeper.exception(1, read_pdu(0x02, 0, 16)))
            if log:
                # Logged once a minute per address and reason: maybe by an earlier test already.
                self.rig.wait_log(log, 5)
                eventually(lambda: self.metric(
                    'ioportd_modbus_connections_refused_total{reason="tls_handshake"}') > before,
                    5, "the refusal counted")
            return what
        finally:
            keeper.close()

    def test_no_client_certificate_is_refused(self):
        self.assert_refused(self.certs.context(None),
                            log=r"refused Modbus client 127\.0\.0\.1: TLS handshake failed: "
                                r"peer did not return a certificate")

    def test_an_expired_certificate_is_refused(self):
        self.assert_refused(self.certs.context("expired"),
                            log=r"TLS handshake failed: certificate verify failed.*: "
                                r"certificate has expired")

    def test_a_certificate_of_another_ca_is_refused(self):
        self.assert_refused(self.certs.context("foreign"),
                            log=r"TLS handshake failed: certificate verify failed.*: "
                                r"unable to get local issuer certificate")

    def test_tls_1_1_is_refused(self):
        context = self.certs.context("operator")
        context.set_ciphers("ALL:@SECLEVEL=0")
        context.minimum_version = ssl.TLSVersion.TLSv1_1
        context.maximum_version = ssl.TLSVersion.TLSv1_1
        what = self.assert_refused(context, log=r"TLS handshake failed: unsupported protocol")
        self.assertIn("handshake failed", what)

    def test_a_plaintext_modbus_frame_on_the_tls_port_gets_no_answer(self):
        what = self.assert_refused(payload=struct.pack(">HHHB", 7, 0, 6, 1) + read_pdu(3, 0, 1),
                                   log=r"TLS handshake failed: (wrong version number|http request"
                                       r"|packet length too long|record layer failure)")
        self.assertIn(what, ("closed", "7 bytes that are no Modbus answer"))

    # --- What the server offers ------------------------------------------------------------

    def s_client(self, *options):
        """Whether a handshake with openssl s_client and these options succeeds."""
        out = subprocess.run(
            ["openssl", "s_client", "-connect", f"127.0.0.1:{self.tls_port}", "-brief",
             "-CAfile", self.certs.path("ca.pem"), "-cert", self.certs.path("operator.pem"),
             "-key", self.certs.path("operator.key"), *options],
            input="", capture_output=True, text=True, timeout=10)
        return "CONNECTION ESTABLISHED" in out.stderr

    def test_s_client_sees_only_tls_1_2_and_1_3_and_the_configured_ciphers(self):
        self.assertTrue(self.s_client("-tls1_3"))
        self.assertTrue(self.s_client("-tls1_2"))
        for old in ("-tls1_1", "-tls1"):
            self.assertFalse(self.s_client(old, "-cipher", "ALL:@SECLEVEL=0"), old)
        # Every TLS 1.2 cipher this OpenSSL knows, one at a time: only ECDHE with an AEAD
        # (the server's key is ECDSA, so the ECDSA ones).
        listed = subprocess.run(["openssl", "ciphers", "-s", "-tls1_2",
                                 "ALL:COMPLEMENTOFALL:@SECLEVEL=0"],
                                capture_output=True, text=True, check=True).stdout.strip()
        tls12 = [c for c in listed.split(":") if not c.startswith("TLS_")]
        self.assertGreater(len(tls12), 20)
        accepted = {c for c in tls12 if self.s_client("-tls1_2", "-cipher", c + ":@SECLEVEL=0")}
        self.assertEqual(accepted, {"ECDHE-ECDSA-AES128-GCM-SHA256",
                                    "ECDHE-ECDSA-AES256-GCM-SHA384",
                                    "ECDHE-ECDSA-CHACHA20-POLY1305"})
        suites = ["TLS_AES_128_GCM_SHA256", "TLS_AES_256_GCM_SHA384",
                  "TLS_CHACHA20_POLY1305_SHA256", "TLS_AES_128_CCM_SHA256",
                  "TLS_AES_128_CCM_8_SHA256"]
        accepted = {s for s in suites if self.s_client("-tls1_3", "-ciphersuites", s)}
        self.assertEqual(accepted, set(suites[:3]))

    def test_a_client_that_reconnects_resumes_its_session_and_keeps_its_role(self):
        for version in (ssl.TLSVersion.TLSv1_2, ssl.TLSVersion.TLSv1_3):
            context = self.certs.context("viewer", maximum_version=version)
            first = TlsClient(self.tls_port, context)
            first.request(1, read_pdu(0x03, 0, 1))  # TLS 1.3: the ticket comes after the handshake
            session = first.socket.session
            first.close()
            mark = self.rig.log_mark()
            raw = socket.create_connection(("127.0.0.1", self.tls_port), timeout=5)
            again = context.wrap_socket(raw, server_hostname="127.0.0.1", session=session)
            try:
                self.assertTrue(again.session_reused, version)
                client = TlsClient.__new__(TlsClient)
                client.socket, client.transaction = again, 0
                wait_online(self.rig)
                self.assertIsNone(client.exception(1, read_pdu(0x03, 0, 1)))
                self.assertEqual(client.exception(1, WRITES[1]), ILLEGAL_FUNCTION)
            finally:
                again.close()
            self.rig.wait_log(r"CN=viewer-1, TLS TLSv1\.[23], resumed\): role viewer", 5, mark)

    # --- Misbehaving clients ----------------------------------------------------------------

    def test_a_slowloris_handshake_is_closed_while_others_are_served(self):
        keeper = self.client("operator")
        try:
            hello = client_hello(self.certs)
            raw = socket.create_connection(("127.0.0.1", self.tls_port), timeout=10)
            started = time.monotonic()
            closed = threading.Event()
            worst = 0.0

            def trickle():
                try:
                    for byte in hello:
                        raw.sendall(bytes([byte]))
                        if closed.wait(0.1):
                            return
                except OSError:
                    pass

            sender = threading.Thread(target=trickle)
            sender.start()
            try:
                # The server says nothing and closes it at the handshake deadline (5 s).
                self.assertEqual(raw.recv(1), b"")
                elapsed = time.monotonic() - started
            except ConnectionResetError:
                elapsed = time.monotonic() - started
            closed.set()
            sender.join()
            raw.close()
            for _ in range(20):
                wait_online(self.rig)
                t = time.monotonic()
                self.assertIsNone(keeper.exception(1, read_pdu(0x02, 0, 16)))
                worst = max(worst, time.monotonic() - t)
            print(f"\n  slowloris handshake closed {elapsed:.2f} s after connecting; an operator's "
                  f"reads meanwhile took at most {worst * 1000:.1f} ms", file=sys.stderr)
            self.assertGreater(elapsed, 4.5)
            self.assertLess(elapsed, 7)
            self.assertLess(worst, 0.5)
            self.rig.wait_log(r"refused Modbus client 127\.0\.0\.1: TLS handshake not complete "
                              r"within 5 s", 5)
        finally:
            keeper.close()

    def test_a_client_that_never_reads_its_responses_is_closed(self):
        """Requests for 125 input registers, pipelined by a client with a 4 KiB receive buffer
        that never reads a response. The server answers until its socket buffer is full of
        responses, then stops reading and closes the connection 5 to 10 s later (a TLS
        response's baseline is taken at the watchdog's first look). The wait is timed from the
        last request the server took (the state API's count of the client's requests): how long
        it takes to fill its buffers is the CPU's business (a sanitized daemon under load takes
        many seconds)."""
        keeper = self.client("operator")
        greedy = TlsClient(self.tls_port, self.certs.context("operator"), receive_buffer=4096)
        port = greedy.socket.getsockname()[1]
        request = struct.pack(">HHHB", 1, 0, 6, 1) + read_pdu(0x04, 200, 125)
        try:
            greedy.socket.setblocking(False)
            sent, stuck_since = 0, None
            while True:
                try:
                    greedy.socket.send(request * 64)
                    sent += 64
                    stuck_since = None
                except ssl.SSLWantWriteError:
                    stuck_since = stuck_since or time.monotonic()
                    if time.monotonic() - stuck_since > 0.5:
                        break  # the server is not reading, or not as fast as this sends
                    select.select([], [greedy.socket], [], 0.01)  # until it takes more
                except (ConnectionError, ssl.SSLError):
                    self.fail(f"closed after {sent} requests, before the buffers were full")
            worst, answered, answered_last, closed_after = 0.0, -1, time.monotonic(), None
            deadline = time.monotonic() + 90
            while time.monotonic() < deadline:
                wait_online(self.rig)
                t = time.monotonic()
                self.assertIsNone(keeper.exception(1, read_pdu(0x02, 0, 16)))
                worst = max(worst, time.monotonic() - t)
                state = [c for c in self.rig.state()["modbus"]["clients"]
                         if c["address"].endswith(f":{port}")]
                if not state:
                    closed_after = time.monotonic() - answered_last
                    break
                if state[0]["requests"] != answered:
                    answered, answered_last = state[0]["requests"], time.monotonic()
                time.sleep(0.1)
            self.assertIsNotNone(closed_after, "the greedy client was not closed within 90 s")
            print(f"\n  a TLS client that never reads: {sent} requests sent, {answered} answered, "
                  f"closed {closed_after:.1f} s after the last; another client's reads took at "
                  f"most {worst * 1000:.1f} ms", file=sys.stderr)
            self.assertGreater(closed_after, 4)
            self.assertLess(closed_after, 15)
            self.assertLess(worst, 0.5)
        finally:
            greedy.close()
            keeper.close()

    def test_silent_connections_to_the_tls_port_lock_no_one_out(self):
        """Issue 23 item 4: silent TCP connections to the TLS port, renewed faster than the
        handshake deadline frees them, held every max_connections place (64 here) and locked
        every new client out of both listeners. An attacker at 127.0.0.2 opens one every 30 ms
        (33/s, 165 per handshake deadline) for 8 s; meanwhile, every 0.2 s, a new plain client
        and a new operator TLS client connect from 127.0.0.1 and must be served, throughout."""
        held, stop = [], threading.Event()
        attack_seconds, at_most = 8.0, 300
        before = self.metric(
            'ioportd_modbus_connections_refused_total{reason="too_many_handshakes"}')

        def attack():
            until = time.monotonic() + attack_seconds
            while time.monotonic() < until and len(held) < at_most and not stop.is_set():
                s = silent(self.tls_port, "127.0.0.2")
                if s:
                    held.append(s)
                stop.wait(0.03)

        attacker = threading.Thread(target=attack)
        started = time.monotonic()
        attacker.start()
        rounds, worst_plain, worst_tls, most_handshakes = 0, 0.0, 0.0, 0
        try:
            while attacker.is_alive():
                into = time.monotonic() - started
                wait_online(self.rig)
                t = time.monotonic()
                try:
                    response = plain_request(self.port, 1, read_pdu(0x02, 0, 16))
                except OSError as error:
                    self.fail(f"{into:.1f} s into the attack a plain client was not served: "
                              f"{error!r}")
                self.assertLess(response[0], 0x80, response.hex())
                worst_plain = max(worst_plain, time.monotonic() - t)
                wait_online(self.rig)
                t = time.monotonic()
                try:
                    operator = self.client("operator")
                    try:
                        self.assertIsNone(operator.exception(1, read_pdu(0x02, 0, 16)))
                    finally:
                        operator.close()
                except (OSError, ssl.SSLError) as error:
                    self.fail(f"{into:.1f} s into the attack an operator's TLS client was not "
                              f"served: {error!r}")
                worst_tls = max(worst_tls, time.monotonic() - t)
                most_handshakes = max(most_handshakes, self.rig.state()["modbus"]["handshakes"])
                rounds += 1
                stop.wait(0.2)
        finally:
            stop.set()
            attacker.join()
            for s in held:
                s.close()
        refused = self.metric(
            'ioportd_modbus_connections_refused_total{reason="too_many_handshakes"}') - before
        print(f"\n  {len(held)} silent connections to the TLS port from one address in "
              f"{attack_seconds:.0f} s: {refused} closed at accept, at most {most_handshakes} "
              f"handshakes in progress; {rounds} new plain and {rounds} new operator TLS clients "
              f"served meanwhile, in at most {worst_plain * 1000:.1f} and "
              f"{worst_tls * 1000:.1f} ms", file=sys.stderr)
        self.assertGreater(len(held), 200)
        self.assertGreater(rounds, 20)
        self.assertLessEqual(most_handshakes, 4)
        self.assertGreater(refused, 150)
        self.rig.wait_log(r"refused Modbus client 127\.0\.0\.2: 4 TLS handshakes of this address "
                          r"in progress \(logged once a minute per address and reason\)")

    def test_handshakes_from_many_addresses_stop_at_max_handshakes(self):
        """Five addresses with 8 silent connections each to the TLS port: 16 handshakes
        (tls.max_handshakes' default) are held, the others closed at accept; plain clients and a
        TLS client connected before are served; once they go, new TLS clients are again."""
        keeper = self.client("operator")
        held = []
        try:
            for _ in range(8):
                for host in range(5):
                    s = silent(self.tls_port, f"127.0.1.{host + 1}")
                    if s:
                        held.append(s)
            eventually(lambda: self.rig.state()["modbus"]["handshakes"] == 16, 5,
                       lambda: f"16 handshakes held: {self.rig.state()['modbus']}")
            self.rig.wait_log(r"refused Modbus client 127\.0\.1\.\d: tls\.max_handshakes \(16\) "
                              r"TLS handshakes in progress")
            wait_online(self.rig)
            self.assertLess(plain_request(self.port, 1, read_pdu(0x02, 0, 16))[0], 0x80)
            self.assertIsNone(keeper.exception(1, read_pdu(0x02, 0, 16)))
        finally:
            for s in held:
                s.close()
        eventually(lambda: self.rig.state()["modbus"]["handshakes"] == 0, 5, "the handshakes gone")
        fresh = self.client("viewer")
        wait_online(self.rig)
        self.assertIsNone(fresh.exception(1, read_pdu(0x02, 0, 1)))
        fresh.close()
        keeper.close()

    def test_plain_modbus_beside_tls_is_a_warning_in_the_log_and_on_the_status_page(self):
        warning = (r'plain Modbus TCP \(modbus\.listen "127\.0\.0\.1:0"\) bypasses the roles of '
                   r"Modbus/TCP Security: any client that reaches it may read and write every unit")
        self.rig.wait_log(r" warning " + warning)
        self.assertTrue(any(re.match(warning, w) for w in self.rig.state()["warnings"]),
                        self.rig.state()["warnings"])

    def test_a_thousand_half_open_tls_connections_cost_the_others_nothing(self):
        keeper = self.client("operator")
        hello = client_hello(self.certs)
        half_open = []
        try:
            for _ in range(1000):
                s = socket.create_connection(("127.0.0.1", self.tls_port), timeout=5)
                s.sendall(hello[:len(hello) // 2])
                half_open.append(s)
            worst = 0.0
            for _ in range(50):
                wait_online(self.rig)
                t = time.monotonic()
                self.assertIsNone(keeper.exception(1, read_pdu(0x02, 0, 16)))
                worst = max(worst, time.monotonic() - t)
            self.assertLess(worst, 0.5)
            # 4 handshakes at once from one address; the rest are closed at accept.
            self.rig.wait_log(r"refused Modbus client 127\.0\.0\.1: 4 TLS handshakes of this "
                              r"address in progress")
            self.assertLessEqual(self.rig.state()["modbus"]["handshakes"], 4)
            # Another address is served at once; this one once the 4 handshake deadlines passed.
            other = TlsClient(self.tls_port, self.certs.context("viewer"), source="127.0.0.3")
            try:
                wait_online(self.rig)
                self.assertIsNone(other.exception(1, read_pdu(0x02, 0, 1)))
            finally:
                other.close()
            opened = time.monotonic()

            def served():
                try:
                    fresh = self.client("viewer")
                except (OSError, ssl.SSLError):
                    return False
                try:
                    return fresh.exception(1, read_pdu(0x02, 0, 1)) is None
                except (OSError, ssl.SSLError):
                    return False
                finally:
                    fresh.close()
            eventually(served, 10, "a new TLS client served after the handshake deadline",
                       interval=0.2)
            print(f"\n  1000 half-open TLS connections: an operator's 50 reads took at most "
                  f"{worst * 1000:.1f} ms; a client of another address served at once, a new one "
                  f"of theirs {time.monotonic() - opened:.1f} s later", file=sys.stderr)
        finally:
            for s in half_open:
                s.close()
            keeper.close()


def client_hello(certs):
    """A real ClientHello's bytes, as a TLS client sends them first: captured from a memory BIO."""
    context = certs.context("operator")
    incoming, outgoing = ssl.MemoryBIO(), ssl.MemoryBIO()
    tls = context.wrap_bio(incoming, outgoing, server_hostname="127.0.0.1")
    try:
        tls.do_handshake()
    except ssl.SSLWantReadError:
        pass
    return outgoing.read()


class Reload(unittest.TestCase):
    """SIGHUP: certificates and roles read anew; open connections keep their role; the plain
    listener turned off."""

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="ioportd-tls-reload-")
        self.certs = make_certificates(self.dir)
        self.rig = Rig(self.dir, IOPORTD, IOPORT_SIM)
        self.addCleanup(self.rig.close)
        self.rig.start_hub("dim16:0,dom16:0")
        self.rig.start_id2()
        self.rig.write_config(config(self.rig, self.certs))
        self.rig.start_daemon()
        self.port = self.rig.listening_port("Modbus TCP")
        self.tls_port = self.rig.listening_port("Modbus/TCP Security (TLS)")
        wait_online(self.rig)  # the reads below answer from the image: 0B until polled

    def tearDown(self):
        shutil.rmtree(self.dir, ignore_errors=True)

    def client(self, name):
        return TlsClient(self.tls_port, self.certs.context(name))

    def test_roles_are_read_anew_and_open_connections_keep_theirs(self):
        before = self.client("norole")
        self.assertEqual(before.exception(1, read_pdu(0x03, 0, 1)), ILLEGAL_FUNCTION)
        log = self.rig.reload(config(self.rig, self.certs, tls_extra="    default_role: viewer\n"))
        self.assertIn("SIGHUP: reloaded", log)
        after = self.client("norole")
        wait_online(self.rig)
        self.assertIsNone(after.exception(1, read_pdu(0x03, 0, 1)))
        self.assertEqual(after.exception(1, WRITES[0]), ILLEGAL_FUNCTION)
        self.assertEqual(before.exception(1, read_pdu(0x03, 0, 1)), ILLEGAL_FUNCTION)
        before.close()
        after.close()
        self.rig.wait_log(r"CN=norole-1, TLS TLSv1\.3\): role viewer default_role \(no role in "
                          r"the certificate\), read")

    def test_a_new_certificate_is_taken_and_a_wrong_key_refused(self):
        open_client = self.client("operator")
        certs = self.certs
        certs.server("server2", "gateway1-renewed")
        log = self.rig.reload(config(self.rig, certs, server="server2"))
        self.assertIn("SIGHUP: reloaded", log)
        fresh = self.client("operator")
        self.assertIn(("commonName", "gateway1-renewed"),
                      [rdn[0] for rdn in fresh.socket.getpeercert()["subject"]])
        fresh.close()
        wait_online(self.rig)
        self.assertIsNone(open_client.exception(1, read_pdu(0x02, 0, 1)))
        # A key that is not the certificate's: the reload is refused, nothing changes.
        shutil.copy(certs.path("operator.key"), certs.path("mismatch.key"))
        shutil.copy(certs.path("server2.pem"), certs.path("mismatch.pem"))
        log = self.rig.reload(config(self.rig, certs, server="mismatch"))
        self.assertIn("is not the key of the certificate", log)
        self.assertIn("the running configuration is kept", log)
        wait_online(self.rig)
        self.assertIsNone(open_client.exception(1, read_pdu(0x02, 0, 1)))
        open_client.close()

    def test_max_connections_counts_both_listeners(self):
        self.assertIn("SIGHUP: reloaded",
                      self.rig.reload(config(self.rig, self.certs, max_connections=2)))
        plain = socket.create_connection(("127.0.0.1", self.port), timeout=5)
        tls = self.client("operator")
        mark = self.rig.log_mark()
        with self.assertRaises((ssl.SSLError, ConnectionError)):
            third = self.client("operator")  # closed at accept: the handshake cannot complete
            third.request(1, read_pdu(0x02, 0, 1))
        refused_plain = socket.create_connection(("127.0.0.1", self.port), timeout=5)
        self.assertEqual(refused_plain.recv(1), b"")
        refused_plain.close()
        self.rig.wait_log(r"refused Modbus client 127\.0\.0\.1: max_connections \(2\) reached",
                          5, mark)
        wait_online(self.rig)
        self.assertIsNone(tls.exception(1, read_pdu(0x02, 0, 1)))
        plain.close()
        tls.close()

    def test_the_plain_listener_can_be_turned_off(self):
        plain = socket.create_connection(("127.0.0.1", self.port), timeout=5)
        plain.close()
        log = self.rig.reload(config(self.rig, self.certs, plain=""))
        self.assertIn("SIGHUP: reloaded", log)
        self.assertIn("Modbus TCP listener closed", self.rig.log_text())
        with self.assertRaises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.1", self.port), timeout=5)
        client = self.client("operator")
        wait_online(self.rig)
        self.assertIsNone(client.exception(1, read_pdu(0x02, 0, 1)))
        client.close()

    def test_without_modbus_listen_tls_turns_plain_modbus_off(self):
        """Issue 23 item 3: with modbus.tls, the plain listener runs only when modbus.listen is
        given; given, it is a warning."""
        self.assertIn("bypasses the roles of Modbus/TCP Security", self.rig.log_text())
        log = self.rig.reload(config(self.rig, self.certs, plain=None))
        self.assertIn("SIGHUP: reloaded", log)
        self.assertIn("Modbus TCP listener closed", log)
        self.assertNotIn("bypasses the roles", log)
        with self.assertRaises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.1", self.port), timeout=5)
        client = self.client("operator")
        wait_online(self.rig)
        self.assertIsNone(client.exception(1, read_pdu(0x02, 0, 1)))
        client.close()
        state = self.rig.state()
        self.assertEqual(state["warnings"], [])
        self.assertEqual(state["modbus"]["listen"], "")


class CommLoss(unittest.TestCase):
    """gateway.md §5.3: only requests a client may make keep the outputs out of their safe
    state. A client whose certificate has no role is answered 01 on everything: however fast it
    asks, the safe state comes on time; a viewer's reads, which are served, hold it off."""

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="ioportd-tls-commloss-")
        self.addCleanup(shutil.rmtree, self.dir, True)
        self.certs = make_certificates(self.dir)
        self.rig = Rig(self.dir, IOPORTD, IOPORT_SIM)
        self.addCleanup(self.rig.close)
        self.rig.start_hub("dim16:0,dom16:0")
        self.rig.start_id2()
        self.rig.write_config(config(self.rig, self.certs,
                                     modbus_extra="  comm_loss_timeout: 1500ms\n"))
        self.rig.start_daemon()
        self.tls_port = self.rig.listening_port("Modbus/TCP Security (TLS)")

    def ask_for(self, client, seconds, expected, mark):
        """Reads by `client` every 20 ms for `seconds`: the time the loss was logged (after the
        log position `mark`), or None; and the log position of the last look, which a next
        client's reads go on from."""
        start = time.monotonic()
        while time.monotonic() - start < seconds:
            self.assertEqual(client.exception(1, read_pdu(0x04, 1000, 1)), expected)
            text = self.rig.log_text()
            if "no Modbus request from any client" in text[mark:]:
                return time.monotonic() - start, len(text)
            mark = len(text)
            time.sleep(0.02)  # the pace of a polling client
        return None, mark

    def test_requests_refused_for_lack_of_rights_do_not_hold_off_the_safe_state(self):
        # Both clients' handshakes first, outside the measurement: under load one can take
        # longer than the timeout, and the norole client's reads must follow the viewer's last.
        viewer = TlsClient(self.tls_port, self.certs.context("viewer"))
        self.addCleanup(viewer.close)
        norole = TlsClient(self.tls_port, self.certs.context("norole"))
        self.addCleanup(norole.close)
        # The viewer first: served, its reads keep the loss away for longer than the timeout.
        declared, mark = self.ask_for(viewer, 2.5, None, self.rig.log_mark())
        self.assertIsNone(declared, "a viewer's reads did not count")
        declared, _ = self.ask_for(norole, 6, ILLEGAL_FUNCTION, mark)
        self.assertIsNotNone(declared, "requests answered 01 held off the safe state for 6 s")
        self.assertLess(declared, 1.5 + 1.5)


class Revocation(unittest.TestCase):
    """Issue 23 item 5: modbus.tls.client_crl, made with openssl ca -revoke and -gencrl, refuses
    revoked certificates at the handshake and on resumption; a SIGHUP that revokes one closes
    its connections."""

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="ioportd-tls-crl-")
        self.addCleanup(shutil.rmtree, self.dir, True)
        self.certs = make_certificates(self.dir)
        for name in ("leaked", "victim", "resumer12", "resumer13"):
            self.certs.client(name, "operator")
        self.certs.crl()  # none revoked yet
        self.rig = Rig(self.dir, IOPORTD, IOPORT_SIM)
        self.addCleanup(self.rig.close)
        self.rig.start_hub("dim16:0,dom16:0")
        self.rig.start_id2()
        self.rig.write_config(self.config())
        self.rig.start_daemon()
        self.tls_port = self.rig.listening_port("Modbus/TCP Security (TLS)")
        wait_online(self.rig)  # the reads below answer from the image: 0B until polled

    def config(self):
        return config(self.rig, self.certs, plain="",
                      tls_extra=f"    client_crl: {self.certs.path('crl.pem')}\n")

    def client(self, name):
        return TlsClient(self.tls_port, self.certs.context(name))

    def revoke(self, name):
        """openssl ca -revoke, -gencrl, SIGHUP: the reload's log."""
        self.certs.revoke(name)
        self.certs.crl()
        log = self.rig.reload(self.config())
        self.assertIn("SIGHUP: reloaded", log)
        return log

    def test_a_revoked_certificate_is_refused_at_the_handshake(self):
        before = self.client("leaked")
        wait_online(self.rig)
        self.assertIsNone(before.exception(1, read_pdu(0x02, 0, 1)))
        before.close()
        self.revoke("leaked")
        what = refused(self.tls_port, self.certs.context("leaked"))
        self.rig.wait_log(r"refused Modbus client 127\.0\.0\.1: TLS handshake failed: "
                          r"certificate verify failed.*: certificate revoked")
        operator = self.client("operator")
        wait_online(self.rig)
        self.assertIsNone(operator.exception(1, read_pdu(0x02, 0, 1)))
        operator.close()
        print(f"\n  a revoked certificate: {what}", file=sys.stderr)

    def test_a_revoked_certificate_cannot_resume_its_session(self):
        """The session was made before the revocation. OpenSSL does not verify a resumed
        session's certificate again, and a connection accepted before the reload resumes in the
        old context's session cache: the server checks the certificate against the new CRL."""
        for version, name in ((ssl.TLSVersion.TLSv1_2, "resumer12"),
                              (ssl.TLSVersion.TLSv1_3, "resumer13")):
            context = self.certs.context(name, maximum_version=version)
            first = TlsClient(self.tls_port, context)
            wait_online(self.rig)
            self.assertIsNone(first.exception(1, read_pdu(0x03, 0, 1)))  # 1.3: the ticket
            session = first.socket.session
            first.close()
            # Accepted now, with the context of now; its handshake comes after the reload.
            raw = socket.create_connection(("127.0.0.1", self.tls_port), timeout=5)
            mark = self.rig.log_mark()
            self.revoke(name)
            again = context.wrap_socket(raw, server_hostname="127.0.0.1", session=session)
            try:
                self.assertTrue(again.session_reused, version)
                client = TlsClient.__new__(TlsClient)
                client.socket, client.transaction = again, 0
                client.request(1, read_pdu(0x03, 0, 1))
                outcome = "served"
            except (ssl.SSLError, ConnectionError) as error:
                outcome = f"refused: {error}"
            finally:
                again.close()
            self.assertTrue(outcome.startswith("refused"), f"{version}: {outcome}")
            self.rig.wait_log(r"refused Modbus client 127\.0\.0\.1: TLS session resumed: "
                              r"certificate revoked \(serial [0-9A-F]+\) by "
                              r"modbus\.tls\.client_crl", 5, mark)
            # A new connection cannot resume it in the new context: a full handshake, refused.
            raw = socket.create_connection(("127.0.0.1", self.tls_port), timeout=5)
            with self.assertRaises((ssl.SSLError, ConnectionError)):
                with context.wrap_socket(raw, server_hostname="127.0.0.1",
                                         session=session) as fresh:
                    self.assertFalse(fresh.session_reused)
                    fresh.sendall(struct.pack(">HHHB", 1, 0, 6, 1) + read_pdu(0x03, 0, 1))
                    if not fresh.recv(1):
                        raise ConnectionError("closed")
            raw.close()

    def test_a_sighup_that_revokes_a_certificate_closes_its_connections(self):
        victim, bystander = self.client("victim"), self.client("operator")
        wait_online(self.rig)
        self.assertIsNone(victim.exception(1, read_pdu(0x02, 0, 1)))
        self.assertIsNone(bystander.exception(1, read_pdu(0x02, 0, 1)))
        log = self.revoke("victim")
        self.assertRegex(log, r"Modbus/TCP Security client 127\.0\.0\.1:\d+ \(O=Plant,"
                              r"CN=victim-1\) closed: its certificate \(serial [0-9A-F]+\) is "
                              r"revoked by the reloaded modbus\.tls\.client_crl")
        with self.assertRaises((ssl.SSLError, ConnectionError)):
            victim.request(1, read_pdu(0x02, 0, 1))
        wait_online(self.rig)
        self.assertIsNone(bystander.exception(1, read_pdu(0x02, 0, 1)))
        victim.close()
        bystander.close()

    def test_a_crl_that_is_no_crl_keeps_the_running_configuration(self):
        operator = self.client("operator")
        with open(self.certs.path("crl.pem"), "w") as f:
            f.write("not a CRL\n")
        log = self.rig.reload(self.config())
        self.assertRegex(log, r"ioportd\.yaml:\d+: modbus\.tls\.client_crl: .*crl\.pem has no "
                              r"PEM CRL")
        self.assertIn("the running configuration is kept", log)
        wait_online(self.rig)
        self.assertIsNone(operator.exception(1, read_pdu(0x02, 0, 1)))
        operator.close()


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1] + sys.argv[3:], verbosity=2)
