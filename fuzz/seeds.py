#!/usr/bin/env python3
"""Writes the seed inputs of the fuzz targets into fuzz/corpus/<target>/seed-*.

The seeds are the wire examples of the shared spec (protocol.md §1 and §2, the seed documents'
known typos included), the YAML example of gateway.md §1 and the repository's example
configurations, Modbus requests against the map of gateway.md §2 (the README's mbpoll
examples among them), request lines of the HTTP side's pages (gateway.md §5.4) with the
label values and strings its writers escape, and Sparkplug B commands, topics and STATE messages
(gateway.md §5.5) as a host or any other client of the broker could send them. Run it again after changing it; the files it writes are committed.
Everything else in the corpus directories was found by libFuzzer (fuzz/run merges it in).
"""

import pathlib
import struct

FUZZ = pathlib.Path(__file__).resolve().parent
REPO = FUZZ.parent
SPEC = REPO.parent / "shared" / "spec"

TYPES = ["dim16", "dom16", "acm3p", "acm3c", "lim16", "rgbdm", "dccim", "dcvim", "mux8m"]


def write(target, name, data):
    directory = FUZZ / "corpus" / target
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"seed-{name}").write_bytes(data)


# --- ioport_reply: byte 0 the module (type + 9 * number), byte 1 the read size - 1 -----------

def ioport(name, module_type, number, stream, read_size=64):
    write("ioport_reply", name,
          bytes([TYPES.index(module_type) + 9 * number, read_size - 1]) + stream)


ioport("dim16-only-i15", "dim16", 0, b"8000\r")
ioport("lim16-lower-case", "lim16", 3, b"beef\r", read_size=1)
ioport("dccim", "dccim", 0, b"FFFF\r")
ioport("dcvim", "dcvim", 7, b"0000\r")
ioport("acm3p-c1", "acm3p", 1, b"3398A0F30FFF\r")
ioport("acm3p-seed-typo-11-digits", "acm3p", 0, b"04003F56FF5\r")
ioport("dom16-ack", "dom16", 0, b"1\r")
ioport("dom16-error-ack", "dom16", 1, b"0\r")
ioport("rgbdm-ack", "rgbdm", 7, b"1\r", read_size=1)
ioport("mux8m-ack", "mux8m", 0, b"1\r")
ioport("noise-then-reply", "dim16", 0, b"\x00\xff\x13garbage\r8000\r", read_size=3)
ioport("too-long", "acm3c", 2, b"3398A0F30FFF00\r3398A0F30FFF\r")
# Requests as the simulator receives them (the device side of the same frames).
ioport("requests", "dom16", 0,
       b"b093D1\rb1596A\rc1\ri005\ri000\rf7O\rf0R\ra0\rh7\r", read_size=5)

# --- id2_reply: byte 0 the command (I C R), byte 1 the read size - 1 --------------------------

def id2(name, command, stream, read_size=64):
    write("id2_reply", name, bytes(["ICR".index(command), read_size - 1]) + stream)


id2("stop-low", "I", b"0\n")
id2("stop-high", "I", b"1\n")
id2("count-42", "C", b"00042\n", read_size=1)
id2("count-max", "C", b"65535\n")
id2("count-over", "C", b"65536\n")
id2("reset-ok", "R", b"OK\n")
id2("requests-and-noise", "C", b"ICR\x00\n12345\n", read_size=2)

# --- config: the file's text ------------------------------------------------------------------

gateway_md = (SPEC / "gateway.md").read_text()
example = gateway_md.split("```yaml\n", 1)[1].split("```", 1)[0]
write("config", "gateway-md-example.yaml", example.encode())
tags = gateway_md.split("### 6.1", 1)[1].split("```yaml\n", 1)[1].split("```", 1)[0]
write("config", "gateway-md-tags.yaml",
      tags.replace("  - name: hub0\n", "  - name: hub0\n    protocol: ioport\n"
                   "    device: /dev/ttyUSB0\n", 1).encode())
for path in sorted((REPO / "config").glob("*.yaml")):
    write("config", path.name, path.read_bytes())
write("config", "tls.yaml", b"""\
modbus:
  listen: ""
  tls:
    listen: "[::]:802"
    certificate: /etc/ioportd/tls/server.pem
    key: /etc/ioportd/tls/server.key
    client_ca: /etc/ioportd/tls/client-ca.pem
    default_role: viewer
    roles:
      operator: { units: all, access: read_write }
      viewer:   { units: [1, 2], access: read }
links:
  - { name: hub0, protocol: ioport, device: /dev/ttyUSB0, unit_id: 1, modules: [{ type: dim16, number: 0 }] }
  - { name: press, protocol: id2, device: /dev/ttyUSB1, unit_id: 2 }
""")
write("config", "every-setting.yaml", b"""\
modbus:
  listen: "[::]:1502"
  max_connections: 4
  idle_timeout: 0
  allow: ["10.0.0.0/8", "192.168.1.7", "fd00::/8", "::1/128", "0.0.0.0/0"]
  read_only: true
  word_order: little
  stale: hold
  keepalive: 90s
  comm_loss_timeout: 2500ms
on_shutdown: initial
log_level: debug
links:
  - name: hub0
    protocol: ioport
    device: /dev/serial/by-id/usb-FTDI_hub0
    baud: 38400
    unit_id: 247
    timeout: 1500us
    retries: 10
    identity:
      vendor_name: "ACME Automation"
      product_code: ioportd-hub0
      vendor_url: "https://example.invalid/hub0"
      product_name: "Remote I/O gateway"
      model_name: hub8u
      user_application_name: "Press line 3, cabinet 7"
    modules:
      - { type: dim16, number: 7, poll: 250ms }
      - { type: dom16, number: 1, initial: 0b1010, safe: 0, refresh: 10ms }
      - { type: rgbdm, number: 2, initial: magenta, safe: red, refresh: 2m }
      - { type: mux8m, number: 3, initial: 0x0702, safe: 0x0707 }
      - { type: acm3c, number: 4 }
      - { type: dccim, number: 5, poll: 0 }
      - { type: dcvim, number: 6 }
      - { type: lim16, number: 0 }
      - { type: acm3p, number: 1 }
  - name: press
    protocol: id2
    device: /dev/ttyS0
    timeout: 10s
    retries: 0
""")
write("config", "tag-errors.yaml", """\
links:
  - name: hub0
    protocol: ioport
    device: /dev/ttyUSB0
    modules:
      - type: acm3c
        number: 1
        name: "supply \\"line\\" 1"
        channels:
          0: { name: "pressure", unit: "bar", scale: [20, 100, 0, 10], range: [0, 6] }
          1: { unit: "\\x85", scale: [4, 4, 0, 1] }
          2: { range: [6, 0], scale: [0, 1e-30, 0, 1e30] }
          3: { name: x }
      - { type: dim16, number: 0, name: "acm3c 1", inputs: { 0: "door open", 16: x } }
      - { type: dom16, number: 0, outputs: { 0: "horn", 1: "lamp" }, inputs: { 0: a } }
      - { type: dccim, number: 0, channels: { 0: { unit: "°C", scale: [0, 6, -40, 85] } } }
""".encode())
write("config", "errors.yaml", b"""\
modbus:
  listen: "[::1]:70000"
  allow: ["10.0.0.1/8", "fd00::/8", "127.0.0.1"]
  idle_timeout: 5x
  read_only: "true"
links:
  - name: hub0
    protocol: ioport
    device: /dev/serial/by-id/usb-FTDI_hub
    baud: 9600
    unit_id: 248
    modules:
      - { type: dom16, number: 0, initial: 0x10000, poll: 1s }
      - { type: dom16, number: 0 }
      - { type: rgbdm, number: 8, initial: purple }
      - { type: mux8m, number: 1, initial: 0x0800, refresh: 1ms }
      - { type: dim17, number: 0 }
  - name: hub0
    protocol: id2
    device: /dev/usb-FTDI_hub
    modules: []
---
links: []
""")

# --- modbus_request: an 11-byte scenario (fuzz/modbus_request.cpp), then the TCP stream -------

def adu(transaction, unit, pdu):
    return struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu


def read(function, address, quantity):
    return struct.pack(">BHH", function, address, quantity)


def write_coils(address, bits):
    packed = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        packed[i // 8] |= bit << (i % 8)
    return struct.pack(">BHHB", 0x0F, address, len(bits), len(packed)) + bytes(packed)


def write_registers(address, values):
    return (struct.pack(">BHHB", 0x10, address, len(values), 2 * len(values))
            + struct.pack(f">{len(values)}H", *values))


def read_write(read_address, read_quantity, write_address, values):
    """FC 23: the write part is done first, then the read part (gateway.md §5.2)."""
    return (struct.pack(">BHHHHB", 0x17, read_address, read_quantity, write_address,
                        len(values), 2 * len(values))
            + struct.pack(f">{len(values)}H", *values))


def identification(code, object_id, mei=0x0E):
    """FC 43 / MEI 14 Read Device Identification: code 1 basic, 2 regular, 3 extended, 4 one."""
    return struct.pack(">BBBB", 0x2B, mei, code, object_id)


EVERYDAY = bytes(11)


def modbus(name, requests, scenario=EVERYDAY):
    write("modbus_request", name, scenario + b"".join(requests))


# The README's mbpoll examples, on unit 1 (the hub) and unit 2 (the ID-2).
modbus("readme-examples", [
    adu(1, 1, read(0x04, 0, 8)),                # input registers 0-7
    adu(2, 1, read(0x04, 200, 6)),              # acm3p 0 in %, float32
    adu(3, 1, struct.pack(">BHH", 0x05, 1, 0xFF00)),  # coil 1: dom16 0 o1 on
    adu(4, 1, struct.pack(">BHH", 0x06, 8, 3)),  # rgbdm 0 blue
    adu(5, 1, read(0x04, 1000, 10)),            # diagnostics
])
modbus("every-function", [
    adu(0x0101, 1, read(0x01, 0, 32)),
    adu(0x0102, 1, read(0x02, 0, 256)),
    adu(0x0103, 1, read(0x03, 0, 24)),
    adu(0x0104, 1, read(0x04, 1100, 72)),
    adu(0x0105, 1, struct.pack(">BHH", 0x05, 17, 0x0000)),
    adu(0x0106, 1, struct.pack(">BHH", 0x06, 16, 0x0102)),
    adu(0x010F, 1, write_coils(10, [1, 0, 1, 1, 0, 0, 1, 1, 1, 0, 1, 0])),
    adu(0x0110, 1, write_registers(0, [0x93D1, 0x596A])),
])
modbus("id2-unit", [
    adu(7, 2, read(0x02, 0, 1)),
    adu(8, 2, read(0x04, 0, 1)),
    adu(9, 2, struct.pack(">BHH", 0x05, 0, 0xFF00)),  # reset the counter
    adu(10, 2, struct.pack(">BHH", 0x05, 0, 0x0000)),  # does nothing
    adu(11, 2, read(0x01, 0, 1)),
    adu(12, 2, read(0x02, 1000, 72)),
])
modbus("exceptions", [
    adu(20, 9, read(0x03, 0, 1)),       # 0A: no such unit
    adu(21, 1, read(0x2B, 0, 1)),       # 01: FC 43 with MEI type 0, not 14
    adu(22, 1, bytes([0xFF])),          # 01, with the high bit already set
    adu(23, 1, read(0x03, 0, 126)),     # 03: over the limit
    adu(24, 1, read(0x04, 80, 1)),      # 02: outside every block
    adu(25, 1, read(0x04, 70, 20)),     # 02: past the end of a block
    adu(26, 1, struct.pack(">BHH", 0x06, 9, 8)),  # 03: colour 8
    adu(27, 1, struct.pack(">BHH", 0x06, 5, 1)),  # 02: dom16 5 is not configured
    adu(28, 1, read(0x04, 16, 1)),
])
modbus("read-only-stale-hold-offline", [
    adu(30, 1, struct.pack(">BHH", 0x05, 0, 0xFF00)),
    adu(31, 1, read(0x04, 0, 80)),
], scenario=bytes([0b011, 0x55, 0xAA, 0xFF, 0x1B, 0xE4, 0, 0, 0, 0, 0]))
modbus("ports-closed", [
    adu(40, 1, write_registers(8, [1, 2])),
    adu(41, 2, struct.pack(">BHH", 0x05, 0, 0xFF00)),
    adu(42, 1, read(0x04, 1000, 10)),
], scenario=bytes([0b011000, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]))
modbus("one-link-devices-fail", [
    adu(50, 0, write_coils(0, [1] * 32)),       # spans dom16 0 and 1; failing devices
    adu(51, 255, write_registers(16, [0x0007])),
    adu(52, 2, read(0x04, 0, 1)),               # no ID-2 now: 0A
], scenario=bytes([0b100, 0, 0, 0, 0, 0, 0, 0, 0, 0b1110, 0b11100111]))
modbus("pipelined-then-malformed", [
    adu(60, 1, read(0x03, 0, 1)) + adu(61, 1, read(0x03, 1, 1)),
    struct.pack(">HHHB", 62, 1, 6, 1) + read(0x03, 0, 1),  # protocol id 1: closed
])
modbus("unfinished", [adu(70, 1, read(0x03, 0, 1))[:10]])
# FC 23 on the harness's hub: dom16 0 and 1 at registers 0-1, rgbdm 0 and 2 at 8 and 10, mux8m 0
# and 4 at 16 and 20.
modbus("read-write-registers", [
    adu(80, 1, read_write(0, 24, 8, [3])),            # rgbdm 0 blue, then every register
    adu(81, 1, read_write(16, 1, 0, [0x1234, 0x5678])),  # spans dom16 0 and 1
    adu(82, 1, read_write(8, 1, 8, [9])),             # 03: colour 9, nothing written
    adu(83, 1, read_write(0, 1, 9, [1])),             # 02: rgbdm 1 is not configured
    adu(84, 1, read_write(20, 5, 0, [1])),            # 02: the read runs past register 23
    adu(85, 1, read_write(0, 126, 0, [1])),           # 03: read quantity over 125
    adu(86, 2, read_write(0, 1, 0, [1])),             # 02: the ID-2 has no holding registers
    adu(87, 1, read(0x04, 1010, 11)),                 # the traffic so far
])
# rgbdm 2 not polled yet; the devices ack, then error-ack, then do not answer.
modbus("read-write-devices-fail", [
    adu(90, 1, read_write(8, 3, 8, [2])),   # written and acked, but the read touches rgbdm 2: 0B
    adu(91, 1, read_write(0, 2, 0, [1, 2])),  # 04 then no answer: 0B, nothing read
    adu(92, 1, read(0x04, 1010, 8)),
], scenario=bytes([0, 0, 0, 0xC0, 0, 0, 0, 0, 0, 0x00, 0x38]))
modbus("device-identification", [
    adu(100, 1, identification(1, 0)),
    adu(101, 1, identification(2, 0)),      # the hub's long objects: more follows at 04
    adu(102, 1, identification(2, 4)),
    adu(103, 1, identification(3, 0)),
    adu(104, 1, identification(4, 6)),
    adu(105, 1, identification(4, 7)),      # 02: no object 07
    adu(106, 1, identification(5, 0)),      # 03: no code 05
    adu(107, 1, identification(1, 0, mei=0x0D)),  # 01: CANopen, not served
    adu(108, 2, identification(1, 3)),      # 03 is not basic: the stream starts at 00
    adu(109, 2, identification(2, 0)),      # ioportd's own objects, all in one response
    adu(110, 9, identification(1, 0)),      # 0A: no such unit
    adu(111, 1, identification(1, 0) + b"\x00"),  # 03: one byte too many
])
# read_only, word_order little, the hub's port closed and its modules never polled, and the
# outputs in their safe state (comm loss) before the first request.
modbus("identification-read-only-comm-loss", [
    adu(120, 1, read(0x04, 1010, 11)),      # 1020 reads 1
    adu(121, 1, identification(2, 0)),      # answered all the same
    adu(122, 1, read_write(0, 1, 0, [1])),  # 01: read_only
    adu(123, 1, read(0x04, 1010, 11)),      # 1020 reads 0
], scenario=bytes([0b1101001, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0, 0]))
# /metrics' labels (gateway.md §5.4): unit ids no link has and function codes outside §3.5
# count under `other`; with the hub alone, 0 and 255 count as the hub's unit.
modbus("metric-labels-other", [
    adu(130, 200, read(0x03, 0, 1)),        # 0A, unit other
    adu(131, 248, bytes([0x41, 0, 0])),     # 0A, unit and function other
    adu(132, 1, bytes([0x07])),             # 01, function other
    adu(133, 1, bytes([0x85, 0, 4, 0xFF, 0])),  # 01, high bit set: other
    adu(134, 0, read(0x04, 0, 1)),          # the hub's unit
    adu(135, 255, bytes([0x2B, 0x0E, 1, 0])),   # the hub's unit, FC 43
], scenario=bytes([0b100, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]))

# --- http_route: a request line "METHOD TARGET", a LF, then the bytes the writers escape and the
# JSON document's operations (fuzz/http_route.cpp) -----------------------------------------------

def http(name, method, target, rest=b"", hosts=None):
    """`hosts`: the Host fields (and "1.0" for HTTP/1.0); None: HTTP/1.1 with Host: localhost."""
    fields = b"" if hosts is None else b"".join(b"\t" + h for h in hosts)
    write("http_route", name, method + b" " + target + fields + b"\n" + rest)


for page in [b"/", b"/app.js", b"/app.css", b"/icon.svg", b"/api/v1/state", b"/api/v1/trends",
             b"/metrics", b"/healthz", b"/map"]:
    label = page.strip(b"/").replace(b"/", b"-") or b"status"
    http(f"get-{label.decode()}", b"GET", page)
    http(f"head-{label.decode()}", b"HEAD", page)
http("post-metrics", b"POST", b"/metrics")
http("put-map", b"PUT", b"/map?format=csv")
http("unknown-trailing-slash", b"GET", b"/metrics/")
http("absolute-form", b"GET", b"http://127.0.0.1:8502/metrics")
http("asterisk", b"OPTIONS", b"*")
http("empty-target", b"GET", b"")
http("map-csv", b"GET", b"/map?format=csv")
http("map-md-escaped", b"GET", b"/map?form%61t=m%64&format=html")
http("map-html-plus", b"HEAD", b"/map?x=a+b&format=html")
http("map-bad", b"GET", b"/map?format=pdf")
http("map-malformed-escape", b"GET", b"/map?format=%zz")
http("map-truncated-escape", b"GET", b"/map?format=csv%2")
# An operator's write (gateway.md §7.1): the body the bytes, its Origin their first line.
http("write", b"POST", b"/api/v1/write",
     b'{"link": "hub0", "module": "dom16_0", "point": "out3", "value": "ON"}')
http("write-origin", b"POST", b"/api/v1/write",
     b'http://localhost\n{"link": "l", "module": "m", "point": "p", "value": true}',
     hosts=[b"localhost"])
http("write-get", b"GET", b"/api/v1/write", b'{"link": 1}')
# The Host against DNS rebinding (gateway.md §5.4): IP literals, localhost, the names; 421 for
# others; 400 for several, none in HTTP/1.1 or a malformed one.
http("host-ipv4-port", b"GET", b"/api/v1/state", hosts=[b"127.0.0.1:8502"])
http("host-ipv6-port", b"GET", b"/api/v1/state", hosts=[b"[::1]:8502"])
http("host-ipv6-scope", b"GET", b"/api/v1/state", hosts=[b"[fe80::1%25eth0]"])
http("host-localhost-dot", b"GET", b"/metrics", hosts=[b"LOCALHOST.:8502"])
http("host-server-name", b"GET", b"/", hosts=[b"Gateway.Plant.Example"])
http("host-machine-name", b"HEAD", b"/healthz", hosts=[b"box7:80"])
http("host-rebinding", b"GET", b"/api/v1/state", hosts=[b"evil.example:8502"])
http("host-rebinding-missing-page", b"POST", b"/nowhere", hosts=[b"evil.example"])
http("host-two", b"GET", b"/metrics", hosts=[b"127.0.0.1", b"evil.example"])
http("host-none-http11", b"GET", b"/metrics", hosts=[])
http("host-none-http10", b"GET", b"/metrics", hosts=[b"1.0"])
http("host-http10-rebinding", b"GET", b"/metrics", hosts=[b"1.0", b"evil.example"])
http("host-bad-port", b"GET", b"/metrics", hosts=[b"127.0.0.1:80x"])
http("host-unbracketed-ipv6", b"GET", b"/metrics", hosts=[b"::1"])
http("host-nul", b"GET", b"/metrics", hosts=[b"[::1\x00x]"])
# The status page's own requests, with a name to look up and a label with every escape.
http("state-query-name", b"GET", b"/api/v1/state?link=hub%200&link=hub1",
     b"link\nhub0 \"dim16 0\" \\ \x00\x01\x1f\x7f caf\xc3\xa9 \xff")
# Every JSON operation once (low 3 bits): object, array, close, string, double, float, integer,
# bool; then NaN and infinity as a double and a float.
http("json-operations", b"GET", b"/metrics",
     b"x\n" + bytes([0, 0x41, 0x42, 1, 3 | (3 << 3)]) + b"a\"\\" + bytes([4]) + b"\x9a\x99\x99\x99\x99\x99\xb9\x3f"
     + bytes([5]) + b"\xcd\xcc\xcc\x3d" + bytes([6 | 8]) + b"\xff" * 8 + bytes([6]) + b"\xff" * 8
     + bytes([7, 7 | 8, 7 | 16, 2, 2])
     + bytes([4]) + b"\x00\x00\x00\x00\x00\x00\xf8\x7f" + bytes([5]) + b"\x00\x00\x80\x7f")


# --- sparkplug: byte 0 the DCMD's device (module type 0..8, 9 the ID-2), then a Sparkplug B
# payload (protobuf, sparkplug_b.proto), also read as a topic and as a STATE message -----------

def varint(n):
    out = bytearray()
    while True:
        byte = n & 0x7F
        n >>= 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def field(number, wire_type, payload):
    tag = varint(number << 3 | wire_type)
    if wire_type == 0:
        return tag + varint(payload)
    if wire_type == 5:
        return tag + payload
    return tag + varint(len(payload)) + payload


def metric(name=None, alias=None, datatype=None, **value):
    out = b""
    if name is not None:
        out += field(1, 2, name.encode())
    if alias is not None:
        out += field(2, 0, alias)
    if datatype is not None:
        out += field(4, 0, datatype)
    for kind, v in value.items():
        if kind == "int":
            out += field(10, 0, v)
        elif kind == "long":
            out += field(11, 0, v)
        elif kind == "float":
            out += field(12, 5, struct.pack("<f", v))
        elif kind == "bool":
            out += field(14, 0, int(v))
        elif kind == "string":
            out += field(15, 2, v.encode())
        elif kind == "null":
            out += field(7, 0, 1)
        elif kind == "template":
            out += field(18, 2, v)
    return out


def template(*members, ref=None, definition=False, version=None):
    """A Template (metric field 18): version 1, members 2, template_ref 4, is_definition 5."""
    out = b"" if version is None else field(1, 2, version.encode())
    for m in members:
        out += field(2, 2, m)
    if ref is not None:
        out += field(4, 2, ref.encode())
    return out + field(5, 0, int(definition))


def payload(*metrics, seq=None):
    out = field(1, 0, 1796183655123)
    for m in metrics:
        out += field(2, 2, m)
    if seq is not None:
        out += field(3, 0, seq)
    return out


def sparkplug(name, device, data):
    write("sparkplug", name, bytes([device]) + data)


DOM16, RGBDM, MUX8M, ID2 = 1, 5, 8, 9
sparkplug("dcmd-out3", DOM16, payload(metric("out/3", datatype=11, bool=True)))
sparkplug("dcmd-word", DOM16, payload(metric("word", datatype=6, int=0x1234)))
sparkplug("dcmd-alias", DOM16, payload(metric(alias=40, datatype=11, bool=False)))
sparkplug("dcmd-colour", RGBDM, payload(metric("colour", datatype=5, int=3)))
sparkplug("dcmd-colour-8", RGBDM, payload(metric("colour", datatype=5, int=8)))
sparkplug("dcmd-colour-uint64", RGBDM, payload(metric("colour", datatype=8, long=3)))
sparkplug("dcmd-pos-neg", MUX8M, payload(metric("pos", datatype=5, int=2),
                                           metric("neg", datatype=5, int=6)))
sparkplug("dcmd-reset", ID2, payload(metric("reset", datatype=11, bool=True)))
sparkplug("dcmd-null", DOM16, payload(metric("word", datatype=6, null=True)))
sparkplug("dcmd-float", DOM16, payload(metric("word", datatype=9, float=1.5)))
sparkplug("dcmd-string", ID2, payload(metric("reset", datatype=12, string="yes")))
sparkplug("ncmd-rebirth", 0, payload(metric("Node Control/Rebirth", datatype=11, bool=True)))
sparkplug("nbirth", 0, payload(metric("bdSeq", datatype=4, long=3),
                               metric("Node Control/Rebirth", alias=0, datatype=11, bool=False),
                               seq=0))
# gateway.md §7.2: a write of a UDT member, as Ignition sends it; a definition; one nested
sparkplug("dcmd-instance", DOM16, payload(metric("dom16", datatype=19, template=template(
    metric("out/3", datatype=11, bool=True), metric("word", datatype=6, int=5), ref="dom16"))))
sparkplug("dcmd-instance-alias", RGBDM, payload(metric(alias=40, datatype=19, template=template(
    metric("colour", int=3), ref="rgbdm"))))
sparkplug("nbirth-definition", 0, payload(metric("_types_/mux8m", datatype=19, template=template(
    metric("pos", datatype=5, null=True), metric("neg", datatype=5, null=True), version="1",
    definition=True)), seq=0))
sparkplug("dcmd-instance-nested", MUX8M, payload(metric("mux8m", datatype=19, template=template(
    metric("pos", datatype=19, template=template(metric("neg", int=1), ref="mux8m")),
    ref="mux8m"))))
sparkplug("topic-dcmd", DOM16, b"spBv1.0/plant1/DCMD/box7/hub0.dom16.0")
sparkplug("topic-state", 0, b"spBv1.0/STATE/scada")
sparkplug("state-online", 0, b'{"online":true,"timestamp":1796183655123}')
sparkplug("state-offline", 0, b'{ "timestamp": 1, "online" : false }')
# the DCMD size limit (issue 23): as many metrics as the device has writable ones, one more, a
# command to an input module, one far beyond the bytes of a dom16's, a protobuf group (which
# Sparkplug does not use and the command walk refuses)
DIM16 = 0
sparkplug("dcmd-all-17", DOM16, payload(*[metric(f"out/{k}", datatype=11, bool=k % 2 == 0)
                                          for k in range(16)], metric("word", datatype=6, int=5)))
sparkplug("dcmd-18-out0", DOM16, payload(*[metric("out/0", datatype=11, bool=True)] * 18))
sparkplug("dcmd-colour-twice", RGBDM, payload(metric("colour", datatype=5, int=3),
                                               metric("colour", datatype=5, int=4)))
sparkplug("dcmd-to-input", DIM16, payload(metric("in/0", datatype=11, bool=True)))
sparkplug("dcmd-oversize", DOM16, payload(*[metric("out/0", datatype=11, bool=True)] * 1500))
sparkplug("dcmd-group", DOM16, payload(metric("out/1", datatype=11, bool=True))
          + varint(9 << 3 | 3) + varint(9 << 3 | 4))
sparkplug("ncmd-five", 0, payload(*[metric("Node Control/Rebirth", datatype=11, bool=True)] * 5))


# --- modbus_security: byte 0 the unit id, byte 1 the function code, byte 2 the default role
# (0 none, 1 operator, 2 viewer, 3 line2), then the role extension's value as a client certificate
# carries it (gateway.md §5.6: the DER of an ASN.1 UTF8String).
def utf8_string(text):
    data = text.encode()
    length = bytes([len(data)]) if len(data) < 0x80 else bytes([0x81, len(data)])
    return b"\x0c" + length + data


def security(name, unit, function, default_role, extension):
    write("modbus_security", name, bytes([unit, function, default_role]) + extension)


security("operator-write", 1, 0x06, 0, utf8_string("operator"))
security("viewer-read", 1, 0x03, 0, utf8_string("viewer"))
security("viewer-write", 1, 0x10, 0, utf8_string("viewer"))
security("line2-other-unit", 1, 0x05, 0, utf8_string("line2"))
security("unknown-role-default-operator", 1, 0x06, 1, utf8_string("admin"))
security("umlaut", 2, 0x17, 2, utf8_string("Bediener-\u00fc"))
security("long-form", 2, 0x04, 0, utf8_string("r" * 200))
security("printable-string", 1, 0x03, 2, b"\x13\x08operator")
security("truncated", 1, 0x03, 2, b"\x0c\x08oper")
security("trailing", 1, 0x03, 2, utf8_string("viewer") + b"\x00")
security("bad-utf8", 1, 0x03, 1, b"\x0c\x02o\xc3")
security("no-extension-default-viewer", 1, 0x0F, 2, b"")


# --- mqtt_inbound: byte 0 the limit in 16 bytes, byte 1 the read size - 1, then what a broker
# sends (MQTT 3.1.1 §2, §3: CONNACK, SUBACK, PUBLISH of each QoS, PINGRESP).
def mqtt_length(n):
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def mqtt_publish(topic, payload, qos=0, packet_id=1, flags=0):
    body = struct.pack(">H", len(topic)) + topic
    if qos:
        body += struct.pack(">H", packet_id)
    return bytes([0x30 | qos << 1 | flags]) + mqtt_length(len(body) + len(payload)) + body + payload


def mqtt_inbound(name, limit16, read_size, stream):
    write("mqtt_inbound", name, bytes([limit16, read_size - 1]) + stream)


CONNACK, SUBACK, PINGRESP = b"\x20\x02\x00\x00", b"\x90\x03\x00\x01\x01", b"\xd0\x00"
DCMD = b"spBv1.0/plant1/DCMD/box7/hub0.dom16.0"
mqtt_inbound("session", 16, 7, CONNACK + SUBACK + mqtt_publish(DCMD, b"\x08\x01", 1) + PINGRESP)
mqtt_inbound("huge-qos0", 2, 13, mqtt_publish(DCMD, b"1" * 600) + PINGRESP)
mqtt_inbound("huge-qos1-dup-retain", 2, 1, mqtt_publish(DCMD, b"1" * 600, 1, 0x1234, 0x09)
             + mqtt_publish(b"a", b"b", 2, 2))
mqtt_inbound("huge-qos2-then-small", 4, 64, mqtt_publish(b"t", b"x" * 100, 2, 9)
             + mqtt_publish(b"t", b"y", 1, 10))
mqtt_inbound("longest-length", 255, 256, b"\x30\xff\xff\xff\x7f\x00\x01a" + b"x" * 1000)
mqtt_inbound("five-length-bytes", 1, 1, b"\x30\x80\x80\x80\x80\x01")
mqtt_inbound("huge-suback", 0, 2, b"\x90\xff\x7f" + b"\x00" * 300)
mqtt_inbound("topic-past-end", 0, 3, b"\x30\x82\x01\xff\xff")
