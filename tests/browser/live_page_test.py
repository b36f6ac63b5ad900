#!/usr/bin/python3
"""The status page of the real ioportd, on the real simulator, in headless Chromium (issue 16
§3): an input changed in the simulator shows on the page without a reload, a faulted module
shows as not online, the Modbus clients connected show with their transport and TLS role, a
refused TLS handshake is counted, the Sparkplug node with its broker away shows the backlog its
store keeps (gateway.md §6.2), the plain MQTT output connected to a real Mosquitto shows what it
published (§6.3), neither the page nor the register map meets a violation of the
Content-Security-Policy of §7.1, the console has no errors, and with no user signed in the page
offers no control.

Then ioportd again with a web configuration (gateway.md §7.1: alice and bob with bcrypt
passwords, alice an operator), signed in through the browser's own Basic authentication:
  - alice's page names her; she switches dom16 0's out3 on the page, the simulator's output
    changes, and while the simulator holds its answer back (0.7 s) the page still shows the old
    state, busy; then the new one; the write is in the page's events as hers;
  - a write to dom16 0 while it does not answer is refused in words (no_answer) under its
    tile, and the switch keeps the confirmed state; no policy violation on her page;
  - a page of another origin (a second server, on localhost), in alice's browser, tries a JSON
    fetch (the browser's preflight is refused), a text/plain fetch without CORS (sent, without
    credentials) and a text/plain form POST of a whole write (sent with her credentials): the
    gateway refuses the form, the output and the link's write counters stay as they were;
  - bob's page names him, read only, and offers no control.
Saves the screenshots to OUTDIR.

Usage: live_page_test.py IOPORTD IOPORT_SIM OUTDIR
"""
import base64
import json
import os
import shutil
import socket
import ssl
import struct
import subprocess
import sys
import tempfile
import threading
import urllib.request
import warnings
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

with warnings.catch_warnings():  # deprecated since 3.11, and still libxcrypt's bcrypt
    warnings.simplefilter("ignore", DeprecationWarning)
    import crypt

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "support"))
import status_page_test  # noqa: E402  (beside this file)
from broker import Broker  # noqa: E402
from certificates import Certificates  # noqa: E402
from rig import Rig, eventually  # noqa: E402

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


def config(rig, certs, directory, broker, web="", timeout="50ms"):
    """ioportd on a simulated hub with every module type but acm3c and a simulated ID-2, plain
    Modbus TCP and Modbus/TCP Security, a Sparkplug node with a store whose broker is away, and
    the plain MQTT output on a broker that is there; `web`: more of the http section; `timeout`:
    the hub's."""
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
{web}links:
  - name: hub0
    protocol: ioport
    device: {rig.hub_link}
    unit_id: 1
    timeout: {timeout}
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


# ---- Operators (gateway.md §7.1) ---------------------------------------------------------------

USERS = {"alice": "alice-secret-1", "bob": "bob-secret-2"}


def web_config(directory):
    """The http section's lines for a web configuration of alice and bob, alice an operator.
    bcrypt at the least cost: the browser signs in on every request until ioportd remembers it."""
    path = os.path.join(directory, "web.yml")
    with open(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "w") as f:
        f.write("basic_auth_users:\n")
        for user, password in USERS.items():
            salt = crypt.mksalt(crypt.METHOD_BLOWFISH, rounds=16)  # $2b$04$
            f.write(f"  {user}: '{crypt.crypt(password, salt)}'\n")
    return f"""  web_config_file: {path}
  operators: ["alice"]
"""


def signed_in(port, user):
    """The page's address with the user's name and password: Chromium answers the 401 with them,
    and sends them with the page's own requests from then on."""
    return f"http://{user}:{USERS[user]}@127.0.0.1:{port}/"


def state_as(port, user):
    request = urllib.request.Request(f"http://127.0.0.1:{port}/api/v1/state", headers={
        "Authorization": "Basic " + base64.b64encode(f"{user}:{USERS[user]}".encode()).decode()})
    with urllib.request.urlopen(request, timeout=5) as reply:
        return json.load(reply)


def out3(rig):
    """dom16 0's output 3 at the simulated device."""
    return int(rig.ctl("get dom16:0").split()[0], 0) >> 3 & 1 == 1


# A page of another origin that tries to write to the gateway with the browser's credentials for
# it: a JSON fetch, which the browser may send only after a preflight the gateway does not
# allow; a text/plain fetch that needs none (its answer unreadable); and a text/plain form the
# test submits, which the browser sends with the credentials. The form's name=value is a whole
# write, its "=" hidden in a first "value" that the second replaces, as a JSON parser takes it:
# a gateway that took text/plain would act on it.
FOREIGN_PAGE = """<!doctype html><title>elsewhere</title>
<form id="form" method="post" enctype="text/plain" action="{write}">
<input name='{{"link":"hub0","module":"dom16_0","point":"out3","value":"'
       value='","value":"{value}"}}'>
</form>
<script>
const body = JSON.stringify({{link: 'hub0', module: 'dom16_0', point: 'out3', value: '{value}'}});
const tries = [
  fetch('{write}', {{method: 'POST', mode: 'cors', credentials: 'include',
                    headers: {{'Content-Type': 'application/json'}}, body}}),
  fetch('{write}', {{method: 'POST', mode: 'no-cors', credentials: 'include',
                    headers: {{'Content-Type': 'text/plain'}}, body}})];
Promise.allSettled(tries).then(outcomes => {{
  window.outcomes = outcomes.map(o => o.status === 'fulfilled' ? 'sent: ' + o.value.type
                                                                : 'refused: ' + o.reason);
  document.title = 'tried';
}});
</script>
"""


class ForeignSite:
    """A second HTTP server, on localhost (another host and port than the gateway's)."""

    def __init__(self, page):
        body = page.encode()

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                self.send_response(200)
                self.send_header("Content-Type", "text/html; charset=utf-8")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://localhost:{self.server.server_address[1]}/elsewhere.html"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


# Chromium says in its console that the write answered 504, as it says of any failed request.
REFUSED_WRITE = (r"api/v1/write - Failed to load resource: the server responded with a status "
                 r"of 504")


def operators(rig, port):
    """The checks of the module's docstring for operators; raises PageTestFailed."""
    sp = status_page_test
    failures = []

    def check(name, fn):
        print(f"live_page_test: {name} ...", flush=True)
        try:
            fn()
        except AssertionError as e:
            print(f"live_page_test: FAIL: {e}", flush=True)
            failures.append(str(e))

    with sp.Browser() as b:
        def alice_writes():
            b.open(signed_in(port, "alice"))
            sp.wait_user(b, "signed in as alice")
            was = out3(rig)
            b.wait_control("out3 shows the device's state", "hub0", "dom16 0", "out3", timeout=15,
                           checked=str(was).lower(), busy=False, disabled=False)
            # The device takes the new state at once and answers 0.7 s later: until the daemon
            # has the answer, the page shows the state confirmed before.
            rig.ctl("fault dom16:0 delay 700ms")
            b.press("hub0", "dom16 0", "out3")
            eventually(lambda: out3(rig) != was, 10, "the device gets the write", interval=0.005)
            early = b.control("hub0", "dom16 0", "out3")
            if early["checked"] != str(was).lower() or not early["busy"]:
                raise sp.PageTestFailed(f"before the device's answer out3 shows {early}, not "
                                        f"{str(was).lower()} and busy")
            b.wait_control("out3 shows the new state once confirmed", "hub0", "dom16 0", "out3",
                           timeout=10, checked=str(not was).lower(), busy=False)
            rig.ctl("fault dom16:0 none")
            sp._wait("the write is in the events as alice's", 10, lambda: True if (
                "alice@127.0.0.1" in b.driver.execute_script(
                    "return document.getElementById('ev').textContent")) else None)
            b.screenshot(os.path.join(OUTDIR, "status-page-operator.png"))

        def refused():
            # Not answering, it keeps the state the device confirmed (gateway.md §3.2).
            was = str(int(rig.ctl("get dom16:0").split()[0], 0) >> 5 & 1 == 1).lower()
            rig.ctl("fault dom16:0 silent")
            sp._wait("dom16 0 no longer online", 10, lambda: True if (
                b.text("hub0", "dom16 0", "status") not in ("", "online")) else None)
            b.press("hub0", "dom16 0", "out5")
            why, _ = sp._wait("the refusal shows", 10,
                              lambda: b.refusal("hub0", "dom16 0") or None)
            if "(no_answer)" not in why:
                raise sp.PageTestFailed(f"the tile says {why!r}, not a no_answer refusal")
            b.wait_control("out5 as confirmed before", "hub0", "dom16 0", "out5", checked=was,
                           busy=False)
            b.clean("alice's page", allowed=[REFUSED_WRITE])
            rig.ctl("fault dom16:0 none")
            eventually(lambda: [m for m in state_as(port, "alice")["links"][0]["modules"]
                                if m["module"] == "dom16 0"][0]["status"] == 1, 10,
                       "dom16 0 online again")

        def foreign_page():
            was = out3(rig)
            writes = state_as(port, "alice")["links"][0]["writes"]
            site = ForeignSite(FOREIGN_PAGE.format(write=f"http://127.0.0.1:{port}/api/v1/write",
                                                   value="OFF" if was else "ON"))
            wrong = []
            try:
                b.open(site.url, status_page=False)
                sp._wait("the page of another origin tried", 10,
                         lambda: True if b.driver.title == "tried" else None)
                outcomes = b.driver.execute_script("return window.outcomes")
                print(f"live_page_test: the other origin's fetches: {outcomes}", flush=True)
                if not outcomes[0].startswith("refused"):
                    wrong.append(f"the JSON fetch of another origin was {outcomes[0]}")
                # Sent, its answer hidden from the page (Chromium gives it no credentials).
                if outcomes[1] != "sent: opaque":
                    wrong.append(f"the text/plain fetch was {outcomes[1]}")
                b.driver.execute_script("document.getElementById('form').submit()")
                answer, _ = sp._wait("the gateway answers the form", 10, lambda: (
                    b.driver.execute_script(
                        "return location.pathname === '/api/v1/write' && document.body"
                        " ? document.body.textContent : null")))
                print(f"live_page_test: the gateway answered the form: {answer}", flush=True)
                # 415 for its type, or 403 for its origin: §7.1 refuses it either way.
                if not any(word in answer for word in ("unsupported_media_type", "forbidden")):
                    wrong.append(f"the form was answered {answer!r}")
            finally:
                site.close()
            if out3(rig) != was:
                wrong.append("a page of another origin switched out3")
            now = state_as(port, "alice")["links"][0]["writes"]
            if now != writes:
                wrong.append(f"a page of another origin made writes: {writes} -> {now}")
            if wrong:
                raise sp.PageTestFailed("; ".join(wrong))

        check("alice switches out3", alice_writes)
        check("a write the module does not answer is refused in words", refused)
        check("a page of another origin cannot write", foreign_page)

    with sp.Browser() as b:
        def bob_reads():
            b.open(signed_in(port, "bob"))
            sp.wait_user(b, "signed in as bob (read only)")
            b.page.require_tile("hub0", "dom16 0", 15)
            b.renders(2)
            sp.wait_no_controls(b, timeout=0)
            b.clean("bob's page")

        check("bob sees no control", bob_reads)
    if failures:
        raise status_page_test.PageTestFailed("%d operator check(s) failed:\n- %s"
                                              % (len(failures), "\n- ".join(failures)))


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
        # A timeout longer than the 0.7 s for which the simulator holds an answer back; acm3p 0
        # answers again, or each poll of it would wait that long.
        rig.stop_daemon()
        rig.ctl("fault acm3p:0 none")
        rig.write_config(config(rig, certs, directory, broker, web_config(directory), "1s"))
        rig.start_daemon()
        operators(rig, rig.listening_port("HTTP"))
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
