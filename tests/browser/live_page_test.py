#!/usr/bin/python3
"""The status page of the real ioportd, on the real simulator, in headless Chromium (issue 16
§3): an input changed in the simulator shows on the page without a reload, a faulted module
shows as not online, the Modbus clients connected show with their transport and TLS role, a
refused TLS handshake is counted, the Sparkplug node with its broker away shows the backlog its
store keeps (gateway.md §6.2), the plain MQTT output connected to a real Mosquitto shows what it
published (§6.3), neither the page nor the register map meets a violation of the
Content-Security-Policy of §7.1, the console has no errors. Saves the screenshots to OUTDIR.

Usage: live_page_test.py IOPORTD IOPORT_SIM OUTDIR
"""
import os
import shutil
import socket
import ssl
import struct
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "support"))
import status_page_test  # noqa: E402  (beside this file)
from broker import Broker  # noqa: E402
from certificates import Certificates  # noqa: E402
from rig import Rig  # noqa: E402

IOPORTD, IOPORT_SIM, OUTDIR = sys.argv[1], sys.argv[2], sys.argv[3]
HUB = "dim16:0,dom16:0,acm3p:0,lim16:0,rgbdm:0,mux8m:0,dccim:0,dcvim:0"


def closed_port():
    """A loopback port nothing listens on (bound, then closed): a broker that is away."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# Names, units and a scale (gateway.md §6.1), as the page shows them.
TAGS = {"acm3p:0": ', name: "boiler 1", channels: { 0: { name: "supply temperature", '
                   'unit: "°C", scale: [0, 100, -20, 150] } }',
        "dim16:0": ', inputs: { 0: "door open", 3: "pump running" }'}


def config(rig, certs, directory, broker):
    """ioportd on a simulated hub with every module type but acm3c and a simulated ID-2, plain
    Modbus TCP and Modbus/TCP Security, a Sparkplug node with a store whose broker is away, and
    the plain MQTT output on a broker that is there."""
    return f"""modbus:
  listen: "127.0.0.1:0"
  tls:
    listen: "127.0.0.1:0"
    certificate: {certs.path('server.pem')}
    key: {certs.path('server.key')}
    client_ca: {certs.path('ca.pem')}
    roles:
      operator: {{ units: all, access: read_write }}
http:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {rig.hub_link}
    unit_id: 1
    timeout: 50ms
    modules:
""" + "".join(f"      - {{ type: {m.split(':')[0]}, number: 0{TAGS.get(m, '')} }}\n"
             for m in HUB.split(",")) + f"""
  - name: press
    protocol: id2
    device: {rig.id2_link}
    baud: 9600
    unit_id: 2
mqtt:
  broker: "mqtt://127.0.0.1:{closed_port()}"
  group_id: plant1
  edge_node_id: box7
  store:
    path: {os.path.join(directory, "store")}
mqtt_json:
  broker: "mqtt://127.0.0.1:{broker.port}"
  topic_prefix: ioportd/box7
"""


READ = struct.pack(">HHHBBHH", 1, 0, 6, 1, 0x04, 0, 1)  # input register 0 of unit 1


def answered(connection):
    """A client kept connected while the page is checked, once the daemon answered it."""
    connection.sendall(READ)
    assert len(connection.recv(64)) > 0, "no answer"
    return connection


def refused_handshake(port, context):
    """A TLS client without a certificate: TLS 1.3 refuses it after the client's Finished."""
    with context.wrap_socket(socket.create_connection(("127.0.0.1", port), timeout=5),
                             server_hostname="127.0.0.1") as tls:
        try:
            tls.sendall(READ)
            assert tls.recv(64) == b"", "a client without a certificate was answered"
        except (ssl.SSLError, ConnectionError):
            pass


def main():
    directory = tempfile.mkdtemp(prefix="ioportd-page-")
    rig = Rig(directory, IOPORTD, IOPORT_SIM)
    clients = []
    broker = Broker(directory)
    try:
        broker.start()
        certs = Certificates(directory)
        certs.client("operator", "operator")
        rig.start_hub(HUB)
        rig.start_id2()
        rig.write_config(config(rig, certs, directory, broker))
        rig.start_daemon()
        url = f"http://127.0.0.1:{rig.listening_port('HTTP')}/"
        modbus_port = rig.listening_port("Modbus TCP")
        tls_port = rig.listening_port("Modbus/TCP Security (TLS)")
        clients.append(answered(socket.create_connection(("127.0.0.1", modbus_port), timeout=5)))
        clients.append(answered(certs.context("operator").wrap_socket(
            socket.create_connection(("127.0.0.1", tls_port), timeout=5),
            server_hostname="127.0.0.1")))
        refused_handshake(tls_port, certs.context())
        # Values a person would recognise on the screenshot.
        rig.ctl("set dim16:0 0x0001")
        rig.ctl("set lim16:0 0x8011")
        rig.ctl("set acm3p:0 13208 41203 4095")
        rig.ctl("set dccim:0 22539")
        rig.ctl("set dcvim:0 49610")
        subprocess.run(["mbpoll", "-1", "-m", "tcp", "-p", str(modbus_port), "-a", "1",
                        "-t", "4", "-r", "1", "127.0.0.1", "0x0808"],
                       capture_output=True, timeout=10, check=True)
        status_page_test.run(
            url,
            change_input=lambda: rig.ctl("set dim16:0 0x000D"),
            expected_word=0x000D,
            fault=lambda: rig.ctl("fault acm3p:0 silent"),
            fault_module="acm3p 0",
            shows=[("mb-listen", f"127.0.0.1:{tls_port} (TLS)"), ("clients", "TLS · operator"),
                   ("clients", "plain TCP"), ("mb-th", "1"),
                   # Both listeners: plain Modbus bypasses the roles (gateway.md §5.6).
                   ("warn-list", "bypasses the roles of Modbus/TCP Security"),
                   # The broker is away: what changes is kept, and the page says how much.
                   ("sp-conn", "not connected"), ("sp-backlog", " records, "),
                   ("sp-oldest", " ago"), ("sp-fwd", "0"),
                   # Plain MQTT: connected, its states and discovery configs published.
                   ("mj-where", "ioportd/box7/# on mqtt://127.0.0.1:"), ("mj-conn", "connected"),
                   ("mj-disc", "under homeassistant/"), ("mj-drop", "0")],
            # 13208 is 20.15 %: -20 + 20.15 × 1.7 = 14.26 °C, one decimal for a 170 °C range.
            tile_shows=[("hub0", "acm3p 0", "boiler 1"), ("hub0", "acm3p 0", "supply temperature"),
                        ("hub0", "acm3p 0", "14.3°C"), ("hub0", "acm3p 0", "62.9%"),
                        ("hub0", "dim16 0", "door open"), ("hub0", "dim16 0", "pump running")],
            # The register map shares the page's style sheet and icon, under the same policy.
            other_pages=["map"],
            screenshot_path=os.path.join(OUTDIR, "status-page.png"))
        print(f"live_page_test: passed; screenshots in {OUTDIR}")
        return 0
    except AssertionError as failure:
        print(f"live_page_test: FAILED: {failure}", file=sys.stderr)
        if rig.daemon:
            print("--- ioportd log ---\n" + rig.log_text(), file=sys.stderr)
        return 1
    finally:
        for client in clients:
            client.close()
        rig.close()
        broker.stop()
        shutil.rmtree(directory, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
