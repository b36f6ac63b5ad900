"""MQTT at the level of its packets, for the tests of what a client or a broker may do that a
library would not: a client that publishes 250 MB in linear time, brokers that play one part
(MQTT 3.1.1 only, a DISCONNECT at once), a front that makes a real broker look like one of
before MQTT 5, and one that holds its SUBACKs back.

    client = RawClient(port, "hostile"); client.publish(topic, payload, seconds); client.close()
    broker = Mqtt311Broker(); broker.start(); ...; broker.levels; broker.connects; broker.close()
    front = Mqtt311Front(real_broker_port); front.start(); ...; front.close()
    front = SubackHoldingFront(real_broker_port); ...; front.sent; front.release.set()
    connect = parse_connect(body)   # a CONNECT's level, flags, properties, client id
"""

import socket
import struct
import threading


def read_packet(conn):
    """One MQTT control packet from `conn`: (first byte, body), or (None, b"") at its end."""
    header = conn.recv(1)
    if not header:
        return None, b""
    length, shift = 0, 0
    while True:
        byte = conn.recv(1)
        if not byte:
            return None, b""
        length |= (byte[0] & 0x7F) << shift
        shift += 7
        if not byte[0] & 0x80:
            break
    body = bytearray()
    while len(body) < length:
        chunk = conn.recv(min(length - len(body), 1 << 20))
        if not chunk:
            return None, b""
        body += chunk
    return header[0], bytes(body)


def remaining_length(n):
    out = bytearray()
    while True:
        out.append((n & 0x7F) | (0x80 if n > 0x7F else 0))
        n >>= 7
        if not n:
            return bytes(out)


def str16(text):
    raw = text.encode()
    return struct.pack(">H", len(raw)) + raw


def varint(data, at):
    """MQTT's variable byte integer at data[at:]: (value, the index after it)."""
    value, shift = 0, 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, at


# MQTT 5 properties of a CONNECT (3.1.2.11): id -> how many bytes its value takes (None: a
# string or binary data with its 2-byte length; "pair": a user property, two strings).
CONNECT_PROPERTIES = {0x11: 4, 0x21: 2, 0x27: 4, 0x22: 2, 0x19: 1, 0x17: 1, 0x26: "pair",
                      0x15: None, 0x16: None}


def parse_connect(body):
    """A CONNECT's body: {"level", "clean", "will", "will_qos", "will_retain", "keepalive",
    "properties" (MQTT 5: id -> value; user properties as a list of pairs), "client_id"}."""
    name_length = struct.unpack(">H", body[:2])[0]
    at = 2 + name_length
    level, flags = body[at], body[at + 1]
    keepalive = struct.unpack(">H", body[at + 2:at + 4])[0]
    at += 4
    properties = {}
    if level == 5:
        length, at = varint(body, at)
        end = at + length
        while at < end:
            key = body[at]
            at += 1
            size = CONNECT_PROPERTIES[key]
            if size == "pair":
                pair = []
                for _ in range(2):
                    n = struct.unpack(">H", body[at:at + 2])[0]
                    pair.append(body[at + 2:at + 2 + n].decode())
                    at += 2 + n
                properties.setdefault(key, []).append(tuple(pair))
            elif size is None:
                n = struct.unpack(">H", body[at:at + 2])[0]
                properties[key] = body[at + 2:at + 2 + n]
                at += 2 + n
            else:
                properties[key] = int.from_bytes(body[at:at + size], "big")
                at += size
    n = struct.unpack(">H", body[at:at + 2])[0]
    client_id = body[at + 2:at + 2 + n].decode()
    return {"level": level, "clean": bool(flags & 0x02), "will": bool(flags & 0x04),
            "will_qos": (flags >> 3) & 3, "will_retain": bool(flags & 0x20),
            "keepalive": keepalive, "properties": properties, "client_id": client_id}


class RawClient:
    """An MQTT 3.1.1 client of a few lines: it connects, publishes at QoS 1 waiting for each
    PUBACK, and disconnects.
    paho 1.6 copies the rest of an outgoing packet at every send(), which makes a 250 MB
    publish quadratic and, on a loaded machine, minutes long; sendall() here is linear."""

    def __init__(self, port, client_id, timeout=10):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        body = str16("MQTT") + bytes([4, 0x02]) + struct.pack(">H", 60) + str16(client_id)
        self.sock.sendall(bytes([0x10]) + remaining_length(len(body)) + body)
        kind, body = read_packet(self.sock)
        if kind != 0x20 or body[1:2] != b"\x00":
            raise AssertionError(f"CONNACK expected, got {kind} {body!r}")
        self.mid = 0

    def publish(self, topic_name, payload, seconds):
        """Publishes at QoS 1 and returns once the broker has acknowledged it within `seconds`
        (the socket's timeout bounds the whole sendall and each wait for a packet)."""
        self.mid += 1
        head = str16(topic_name) + struct.pack(">H", self.mid)
        self.sock.settimeout(seconds)
        self.sock.sendall(bytes([0x32]) + remaining_length(len(head) + len(payload)) + head)
        self.sock.sendall(payload)
        kind, body = read_packet(self.sock)
        if kind != 0x40 or struct.unpack(">H", body[:2])[0] != self.mid:
            raise AssertionError(f"PUBACK of {self.mid} expected, got {kind} {body!r}")

    def close(self):
        try:
            self.sock.sendall(bytes([0xE0, 0]))
        except OSError:
            pass  # the broker has closed it already (a session taken over)
        self.sock.close()


class ScriptedBroker(threading.Thread):
    """A listener on a free loopback port whose serve(conn) plays one part of a broker, on each
    connection in a thread of its own."""

    def __init__(self):
        super().__init__(daemon=True)
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]

    def run(self):
        while True:
            try:
                conn, _ = self.server.accept()
            except OSError:
                return
            threading.Thread(target=self.serve, args=(conn,), daemon=True).start()

    def close(self):
        self.server.close()


class Mqtt311Broker(ScriptedBroker):
    """A broker that speaks MQTT 3.1.1 only, as brokers from before MQTT 5 do: a CONNECT of
    another protocol level gets CONNACK 0x01 (unacceptable protocol level) and the connection
    closed; a 3.1.1 one gets CONNACK 0, then SUBACKs, PUBACKs and PINGRESPs, and what is published
    to it is dropped. `levels`: the protocol level of every CONNECT, in order; `connects`: each
    CONNECT parsed (parse_connect). With `silent`, another level gets no CONNACK: the connection
    is closed, as RabbitMQ 3.10 does."""

    def __init__(self, silent=False):
        super().__init__()
        self.silent = silent
        self.levels, self.connects = [], []

    def serve(self, conn):
        with conn:
            try:
                kind, body = read_packet(conn)
                connect = parse_connect(body)
                self.connects.append(connect)
                self.levels.append(connect["level"])
                if connect["level"] != 4:
                    if not self.silent:
                        conn.sendall(bytes([0x20, 2, 0, 1]))
                    return
                conn.sendall(bytes([0x20, 2, 0, 0]))
                while (packet := read_packet(conn))[0] is not None:
                    kind, body = packet
                    if kind >> 4 == 8:  # SUBSCRIBE: granted QoS 1 for each filter
                        conn.sendall(bytes([0x90, 3]) + body[:2] + b"\x01")
                    elif kind >> 4 == 3 and (kind >> 1) & 3 == 1:  # PUBLISH at QoS 1
                        at = 2 + struct.unpack(">H", body[:2])[0]
                        conn.sendall(bytes([0x40, 2]) + body[at:at + 2])
                    elif kind >> 4 == 12:  # PINGREQ
                        conn.sendall(bytes([0xD0, 0]))
            except (OSError, IndexError, KeyError):
                pass


class Mqtt311Front(ScriptedBroker):
    """A real broker as one from before MQTT 5 sees it: a CONNECT of another level than 3.1.1
    gets CONNACK 0x01 and the connection closed, as Mqtt311Broker's; a 3.1.1 one is passed on to
    the broker on `port`, and from then on the bytes both ways. `levels`, `connects`, `silent`:
    as Mqtt311Broker's."""

    def __init__(self, port, silent=False):
        super().__init__()
        self.upstream = port
        self.silent = silent
        self.levels, self.connects = [], []

    def serve(self, conn):
        try:
            kind, body = read_packet(conn)
            if kind is None:
                conn.close()
                return
            connect = parse_connect(body)
            self.connects.append(connect)
            level = connect["level"]
            self.levels.append(level)
            if level != 4:
                if not self.silent:
                    conn.sendall(bytes([0x20, 2, 0, 1]))
                conn.close()
                return
            broker = socket.create_connection(("127.0.0.1", self.upstream))
            broker.sendall(bytes([kind]) + remaining_length(len(body)) + body)
        except (OSError, IndexError, KeyError):
            conn.close()
            return
        threading.Thread(target=self.pump, args=(broker, conn), daemon=True).start()
        self.pump(conn, broker)

    @staticmethod
    def pump(source, sink):
        """The bytes of `source` to `sink` until either ends; then both are shut."""
        try:
            while data := source.recv(1 << 16):
                sink.sendall(data)
        except OSError:
            pass
        shut_both(source, sink)


def shut_both(source, sink):
    """The end of a relay from `source` to `sink`: both shut, `source` closed."""
    for end in (source, sink):
        try:
            end.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
    source.close()


class SubackHoldingFront(ScriptedBroker):
    """A real broker (on `port`) whose SUBACKs, and all it sends after one, wait until `release`
    is set, as a broker does that has not taken a SUBSCRIBE yet (or never will: RabbitMQ closes
    the connection at one it cannot serve). `sent`: what the client sent meanwhile and after,
    in order: (packet type, the topic of a PUBLISH or SUBSCRIBE's first filter, else None)."""

    def __init__(self, port):
        super().__init__()
        self.upstream = port
        self.release = threading.Event()
        self.sent = []

    def serve(self, conn):
        try:
            broker = socket.create_connection(("127.0.0.1", self.upstream))
        except OSError:
            conn.close()
            return
        threading.Thread(target=self.pump, args=(broker, conn, False), daemon=True).start()
        self.pump(conn, broker, True)

    def pump(self, source, sink, from_client):
        """Packet by packet from `source` to `sink` until either ends; then both are shut."""
        try:
            while (packet := read_packet(source))[0] is not None:
                kind, body = packet
                if from_client:
                    self.sent.append((kind >> 4, self.topic(kind, body)))
                elif kind >> 4 == 9:  # SUBACK
                    self.release.wait()
                sink.sendall(bytes([kind]) + remaining_length(len(body)) + body)
        except (OSError, IndexError, struct.error):
            pass
        shut_both(source, sink)

    @staticmethod
    def topic(kind, body):
        if kind >> 4 == 3:  # PUBLISH: the topic first
            n = struct.unpack(">H", body[:2])[0]
            return body[2:2 + n].decode("utf-8", "replace")
        if kind >> 4 == 8:  # SUBSCRIBE of MQTT 5: packet id, properties, then the filters
            length, at = varint(body, 2)
            at += length
            n = struct.unpack(">H", body[at:at + 2])[0]
            return body[at + 2:at + 2 + n].decode("utf-8", "replace")
        return None
