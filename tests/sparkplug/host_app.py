"""A Sparkplug B 3.0 host application for the tests: it watches spBv1.0/#, decodes every
message, keeps the view a SCADA host would keep of every edge node, and checks the rules of the
specification that an edge node must keep. A broken rule is recorded in `violations` (never
skipped, never raised in the MQTT thread): a test asserts the list is empty at its end.

Rules checked, per edge node (group, node):
  - births before data: nothing but NBIRTH from a node that is not born (no NDATA, DBIRTH,
    DDATA, DDEATH before NBIRTH); no DDATA or DDEATH for a device before its DBIRTH in the
    session (a DDEATH ends the device's birth);
  - NBIRTH: seq 0, a bdSeq metric, Node Control/Rebirth; every other message of the node but
    NDEATH carries seq, one more (mod 256) than the node's previous message since NBIRTH;
    NDEATH carries no seq;
  - NDEATH: its bdSeq equals that of the NBIRTH of the session it ends;
  - every NDATA/DDATA metric (alias or name) was announced in the NBIRTH/DBIRTH, with the
    same datatype; a metric whose value equals the last known value is a violation (data only on
    change); aliases are unique across the node (node metrics and all devices), names unique per
    birth; every payload decodes and has a timestamp;
  - a metric marked is_historical (store-and-forward, gateway.md §6.2) has its timestamp, and is
    history: it is checked against the birth but neither changes the host's view nor counts as
    data on change.
The host app's own (re)connection to the broker forgets every node: it may have missed messages,
so the next message from each node must be an NBIRTH again (which is what a node does after a
broker restart).

It can publish NCMD rebirth, DCMD (by name or alias, typed) and STATE for a primary host id, and
wait (with a deadline, by polling its record under a condition variable) for a message type,
device or metric value.
"""
import json
import struct
import threading
import time

import paho.mqtt.client as mqtt

import sparkplug_b_pb2 as pb

PREFIX = "spBv1.0"
NODE_TYPES = {"NBIRTH", "NDEATH", "NDATA", "NCMD"}
DEVICE_TYPES = {"DBIRTH", "DDEATH", "DDATA", "DCMD"}

# Sparkplug 3.0 §6.4.16
DATATYPES = {name: number for number, name in enumerate(
    ["Unknown", "Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64", "Float",
     "Double", "Boolean", "String", "DateTime", "Text", "UUID", "DataSet", "Bytes", "File",
     "Template"])}
TYPE_NAMES = {number: name for name, number in DATATYPES.items()}
INT_TYPES = {"Int8", "Int16", "Int32", "UInt8", "UInt16", "UInt32"}
LONG_TYPES = {"Int64", "UInt64", "DateTime"}


class Metric:
    """A decoded metric: value None for is_null."""

    def __init__(self, name, alias, datatype, value, timestamp, is_historical=False):
        self.name, self.alias, self.datatype, self.value = name, alias, datatype, value
        self.timestamp, self.is_historical = timestamp, is_historical

    def __repr__(self):
        return (f"Metric({self.name!r}, alias={self.alias}, "
                f"{TYPE_NAMES.get(self.datatype, self.datatype)}, {self.value!r})")


class Message:
    """One message as received: topic parts, seq, timestamp, metrics; `resolved` maps each
    metric to its name as the host knows it (aliases resolved through the births)."""

    def __init__(self, index, received, topic, type_, group, node, device, payload):
        self.index, self.received, self.topic, self.type = index, received, topic, type_
        self.group, self.node, self.device = group, node, device
        self.payload = payload  # raw bytes
        self.seq = None
        self.timestamp = None
        self.metrics = []
        self.resolved = {}  # name -> value, for DATA and BIRTH: current values
        self.historical = []  # (name, value, timestamp) of DATA metrics marked is_historical
        self.state = None  # STATE: the decoded JSON

    def metric(self, name):
        for m in self.metrics:
            if m.name == name:
                return m
        return None

    def __repr__(self):
        where = f"{self.node}/{self.device}" if self.device else f"{self.node}"
        return (f"#{self.index} {self.type} {where} seq={self.seq} "
                f"{self.resolved or self.state or self.metrics}")


def decode_value(metric):
    if metric.HasField("is_null") and metric.is_null:
        return None
    kind = metric.WhichOneof("value")
    if kind is None:
        return None
    return getattr(metric, kind)


def encode_value(metric, datatype, value):
    """Sets a protobuf metric's value field by Sparkplug datatype (its name or number)."""
    name = TYPE_NAMES[datatype] if isinstance(datatype, int) else datatype
    metric.datatype = DATATYPES[name]
    if value is None:
        metric.is_null = True
    elif name == "Boolean":
        metric.boolean_value = value
    elif name in INT_TYPES:
        metric.int_value = value & 0xFFFFFFFF
    elif name in LONG_TYPES:
        metric.long_value = value & 0xFFFFFFFFFFFFFFFF
    elif name == "Float":
        metric.float_value = value
    elif name == "Double":
        metric.double_value = value
    elif name in ("String", "Text", "UUID"):
        metric.string_value = value
    else:
        raise ValueError(f"no encoding for {name}")


def same_value(a, b, datatype):
    if a is None or b is None:
        return a is None and b is None
    if TYPE_NAMES.get(datatype) == "Float":
        # both came off the wire as float32: compare the bits, so that NaN == NaN
        return struct.pack("<f", a) == struct.pack("<f", b)
    return a == b


class DeviceState:
    def __init__(self):
        self.born = False
        self.by_alias = {}  # alias -> (name, datatype)
        self.by_name = {}  # name -> (alias, datatype)
        self.values = {}  # name -> value


class NodeState:
    def __init__(self):
        self.born = False
        self.bdseq = None
        self.last_seq = None
        self.node_metrics = DeviceState()  # the node's own metrics, from NBIRTH
        self.devices = {}
        self.sessions = 0  # NBIRTHs seen


class HostApp:
    def __init__(self, port, host="127.0.0.1", client_id="ioportd-test-host"):
        self.violations = []
        self.messages = []
        self.nodes = {}
        self.connects = 0
        self._cond = threading.Condition()
        self._client = mqtt.Client(client_id=client_id, clean_session=True,
                                   protocol=mqtt.MQTTv311)
        self._client.on_connect = self._on_connect
        self._client.on_message = self._on_message
        # A broker restart is followed by the node's reconnect 1 s later: be back well before.
        self._client.reconnect_delay_set(0.05, 0.2)
        self._client.connect_async(host, port, keepalive=10)
        self._client.loop_start()
        self.wait(lambda: self.connects > 0, 10, "the host app's connection to the broker")

    def close(self):
        self._client.disconnect()
        self._client.loop_stop()

    # --- receiving -----------------------------------------------------------------------------

    def _on_connect(self, client, userdata, flags, rc):
        if rc != 0:
            return
        # Subscribe before counting the connection: a waiter on `connects` may publish at once.
        client.subscribe(f"{PREFIX}/#", qos=1)
        with self._cond:
            # What happened while away is unknown: every node must be born again.
            for state in self.nodes.values():
                state.born = False
                state.last_seq = None
                for device in state.devices.values():
                    device.born = False
            self.connects += 1
            self._cond.notify_all()

    def violation(self, message, text):
        self.violations.append(f"{message!r}: {text}" if message else text)

    def _on_message(self, client, userdata, msg):
        try:
            with self._cond:
                self._receive(msg.topic, msg.payload)
                self._cond.notify_all()
        except Exception as e:  # a bug here must show up, not vanish in paho's thread
            with self._cond:
                self.violations.append(f"host app error on {msg.topic}: {e!r}")
                self._cond.notify_all()

    def _receive(self, topic, payload):
        parts = topic.split("/")
        index = len(self.messages)
        if len(parts) == 3 and parts[0] == PREFIX and parts[1] == "STATE":
            message = Message(index, time.monotonic(), topic, "STATE", None, parts[2], None,
                              payload)
            try:
                message.state = json.loads(payload)
            except ValueError:
                message.state = None
            self.messages.append(message)
            return
        if len(parts) not in (4, 5) or parts[0] != PREFIX:
            self.violation(None, f"topic outside the Sparkplug namespace: {topic}")
            return
        group, type_, node = parts[1], parts[2], parts[3]
        device = parts[4] if len(parts) == 5 else None
        message = Message(index, time.monotonic(), topic, type_, group, node, device, payload)
        self.messages.append(message)
        if type_ not in NODE_TYPES | DEVICE_TYPES:
            self.violation(message, f"unknown message type {type_}")
            return
        if (type_ in DEVICE_TYPES) != (device is not None):
            self.violation(message, "device id present/absent against the message type")
            return
        decoded = pb.Payload()
        try:
            decoded.ParseFromString(payload)
        except Exception as e:
            self.violation(message, f"payload does not decode: {e}")
            return
        message.seq = decoded.seq if decoded.HasField("seq") else None
        message.timestamp = decoded.timestamp if decoded.HasField("timestamp") else None
        message.metrics = [
            Metric(m.name if m.HasField("name") else None, m.alias if m.HasField("alias") else None,
                   m.datatype if m.HasField("datatype") else None, decode_value(m),
                   m.timestamp if m.HasField("timestamp") else None,
                   m.HasField("is_historical") and m.is_historical)
            for m in decoded.metrics]
        if type_ in ("NCMD", "DCMD"):
            return  # commands: ours, or another host's; not the node's to keep rules on
        if message.timestamp is None:
            self.violation(message, "payload without timestamp")
        state = self.nodes.setdefault((group, node), NodeState())
        getattr(self, "_" + type_.lower())(state, message)

    def _check_seq(self, state, message):
        if message.seq is None:
            self.violation(message, "no seq")
            return
        if not 0 <= message.seq <= 255:
            self.violation(message, f"seq {message.seq} outside 0..255")
        if state.last_seq is not None and message.seq != (state.last_seq + 1) % 256:
            self.violation(message, f"seq {message.seq} after {state.last_seq}")
        state.last_seq = message.seq

    def _announce(self, state, device_state, message, owner):
        """The metrics of a birth: names unique in it, aliases unique across the node."""
        device_state.by_alias, device_state.by_name, device_state.values = {}, {}, {}
        taken = {}
        taken.update({a: "node" for a in state.node_metrics.by_alias} if owner != "node" else {})
        for device_id, other in state.devices.items():
            if device_id != owner:
                taken.update({a: device_id for a in other.by_alias})
        for m in message.metrics:
            if not m.name:
                self.violation(message, f"birth metric without a name: {m!r}")
                continue
            if m.name in device_state.by_name:
                self.violation(message, f"metric {m.name} twice in one birth")
            if m.datatype is None:
                self.violation(message, f"birth metric {m.name} without datatype")
            if m.alias is not None:
                if m.alias in device_state.by_alias:
                    self.violation(message, f"alias {m.alias} twice in one birth")
                if m.alias in taken:
                    self.violation(message,
                                   f"alias {m.alias} of {m.name} is already {taken[m.alias]}'s")
                device_state.by_alias[m.alias] = (m.name, m.datatype)
            device_state.by_name[m.name] = (m.alias, m.datatype)
            device_state.values[m.name] = m.value
            message.resolved[m.name] = m.value

    def _data(self, device_state, message):
        seen = set()
        for m in message.metrics:
            if m.alias is not None and m.alias in device_state.by_alias:
                name, datatype = device_state.by_alias[m.alias]
                if m.name and m.name != name:
                    self.violation(message, f"alias {m.alias} is {name}, not {m.name}")
            elif m.name and m.name in device_state.by_name:
                name, datatype = m.name, device_state.by_name[m.name][1]
            else:
                self.violation(message, f"metric not announced in the birth: {m!r}")
                continue
            if m.datatype is not None and m.datatype != datatype:
                self.violation(message, f"{name}: datatype {m.datatype} but {datatype} in birth")
            if m.is_historical:
                # A stored value (store-and-forward): history, not the current state, so it
                # neither changes the view nor counts as data on change.
                if m.timestamp is None:
                    self.violation(message, f"historical {name} without its timestamp")
                message.historical.append((name, m.value, m.timestamp))
                continue
            if name in seen:
                self.violation(message, f"{name} twice in one message")
            seen.add(name)
            if same_value(device_state.values.get(name), m.value, datatype):
                self.violation(message, f"{name} = {m.value!r} unchanged: data only on change")
            device_state.values[name] = m.value
            message.resolved[name] = m.value

    def _nbirth(self, state, message):
        if message.seq != 0:
            self.violation(message, f"NBIRTH seq {message.seq}, not 0")
        bdseq = message.metric("bdSeq")
        if bdseq is None or bdseq.value is None:
            self.violation(message, "NBIRTH without bdSeq")
        if message.metric("Node Control/Rebirth") is None:
            self.violation(message, "NBIRTH without Node Control/Rebirth")
        if state.born and bdseq is not None and bdseq.value != state.bdseq:
            # A new session without the old one's NDEATH: only if the old connection was lost
            # where the host could not see it, which the host's reconnect would have cleared.
            self.violation(message, f"NBIRTH bdSeq {bdseq.value} while the session of bdSeq "
                                    f"{state.bdseq} had no NDEATH")
        state.born = True
        state.sessions += 1
        state.bdseq = bdseq.value if bdseq is not None else None
        state.last_seq = message.seq
        state.devices = {}
        state.node_metrics = DeviceState()
        state.node_metrics.born = True
        self._announce(state, state.node_metrics, message, "node")

    def _ndeath(self, state, message):
        if message.seq is not None:
            self.violation(message, f"NDEATH with seq {message.seq}")
        bdseq = message.metric("bdSeq")
        if bdseq is None:
            self.violation(message, "NDEATH without bdSeq")
        elif state.born and bdseq.value != state.bdseq:
            self.violation(message, f"NDEATH bdSeq {bdseq.value} ends the session of NBIRTH "
                                    f"bdSeq {state.bdseq}")
        state.born = False
        state.last_seq = None
        for device in state.devices.values():
            device.born = False

    def _born_node(self, state, message):
        if not state.born:
            self.violation(message, f"{message.type} before NBIRTH")
            return False
        self._check_seq(state, message)
        return True

    def _ndata(self, state, message):
        if self._born_node(state, message):
            self._data(state.node_metrics, message)

    def _dbirth(self, state, message):
        if not self._born_node(state, message):
            return
        device = state.devices.setdefault(message.device, DeviceState())
        device.born = True
        self._announce(state, device, message, message.device)

    def _ddata(self, state, message):
        if not self._born_node(state, message):
            return
        device = state.devices.get(message.device)
        if device is None or not device.born:
            self.violation(message, "DDATA before the device's DBIRTH")
            return
        self._data(device, message)

    def _ddeath(self, state, message):
        if not self._born_node(state, message):
            return
        device = state.devices.get(message.device)
        if device is None or not device.born:
            self.violation(message, "DDEATH of a device not born")
            return
        device.born = False

    # --- the host's view ----------------------------------------------------------------------

    def node(self, group, node):
        with self._cond:
            return self.nodes.get((group, node))

    def value(self, group, node, device, name):
        """The last known value of a metric (None: unknown or null)."""
        with self._cond:
            state = self.nodes.get((group, node))
            if state is None:
                return None
            where = state.node_metrics if device is None else state.devices.get(device)
            return None if where is None else where.values.get(name)

    def alias(self, group, node, device, name):
        with self._cond:
            return self.nodes[(group, node)].devices[device].by_name[name][0]

    def datatype(self, group, node, device, name):
        with self._cond:
            return self.nodes[(group, node)].devices[device].by_name[name][1]

    def mark(self):
        """A point in the record: the messages that come after it are `since(mark)`."""
        with self._cond:
            return len(self.messages)

    def since(self, mark, type_=None, device=None, node=None):
        with self._cond:
            return [m for m in self.messages[mark:]
                    if (type_ is None or m.type == type_)
                    and (device is None or m.device == device)
                    and (node is None or m.node == node)]

    # --- waiting --------------------------------------------------------------------------------

    def wait(self, condition, timeout, what):
        """Until condition() (called under the lock) holds, else AssertionError naming `what`."""
        until = time.monotonic() + timeout
        with self._cond:
            while True:
                result = condition()
                if result:
                    return result
                left = until - time.monotonic()
                if left <= 0:
                    tail = "\n  ".join(repr(m) for m in self.messages[-8:])
                    raise AssertionError(
                        f"not within {timeout} s: {what}; last messages:\n  {tail}")
                self._cond.wait(left)

    def wait_message(self, type_, device=None, since=0, timeout=5, where=None, node=None):
        """The first message of `type_` (and device, node) after mark `since` for which
        where(message) holds."""
        def found():
            for m in self.messages[since:]:
                if (m.type == type_ and (device is None or m.device == device)
                        and (node is None or m.node == node) and (where is None or where(m))):
                    return m
            return None
        return self.wait(found, timeout, f"{type_} {device or ''} after #{since}")

    def wait_metric(self, device, name, value, since=0, timeout=5, type_=None):
        """The first DATA or BIRTH message of `device` (None: the node) after `since` that sets
        metric `name` to `value`."""
        types = {type_} if type_ else ({"DDATA", "DBIRTH"} if device else {"NDATA", "NBIRTH"})

        def found():
            for m in self.messages[since:]:
                if (m.type in types and m.device == device and name in m.resolved
                        and m.resolved[name] == value):
                    return m
            return None
        return self.wait(found, timeout, f"{device}/{name} = {value!r} after #{since}")

    # --- publishing -----------------------------------------------------------------------------

    def _publish(self, topic, payload, qos=1, retain=False):
        info = self._client.publish(topic, payload, qos=qos, retain=retain)
        info.wait_for_publish(5)

    def rebirth(self, group, node, value=True):
        payload = pb.Payload(timestamp=int(time.time() * 1000))
        m = payload.metrics.add(name="Node Control/Rebirth")
        encode_value(m, "Boolean", value)
        self._publish(f"{PREFIX}/{group}/NCMD/{node}", payload.SerializeToString())

    def ncmd_next_server(self, group, node):
        payload = pb.Payload(timestamp=int(time.time() * 1000))
        m = payload.metrics.add(name="Node Control/Next Server")
        encode_value(m, "Boolean", True)
        self._publish(f"{PREFIX}/{group}/NCMD/{node}", payload.SerializeToString())

    def dcmd(self, group, node, device, metrics):
        """metrics: a list of dicts with `value` and `name` or `alias`; `datatype` (a name or
        number) defaults to the one of the metric's DBIRTH."""
        payload = pb.Payload(timestamp=int(time.time() * 1000))
        for spec in metrics:
            m = payload.metrics.add()
            if spec.get("name") is not None:
                m.name = spec["name"]
            if spec.get("alias") is not None:
                m.alias = spec["alias"]
            datatype = spec.get("datatype")
            if datatype is None:
                with self._cond:
                    known = self.nodes[(group, node)].devices[device]
                    if spec.get("name") is not None:
                        datatype = known.by_name[spec["name"]][1]
                    else:
                        datatype = known.by_alias[spec["alias"]][1]
            encode_value(m, datatype, spec["value"])
        self._publish(f"{PREFIX}/{group}/DCMD/{node}/{device}", payload.SerializeToString())

    def state(self, host_id, online, retain=True, timestamp=None):
        if timestamp is None:
            timestamp = int(time.time() * 1000)
        body = json.dumps({"online": online, "timestamp": timestamp})
        self._publish(f"{PREFIX}/STATE/{host_id}", body, qos=1, retain=retain)

    def publish_raw(self, topic, payload, retain=False):
        self._publish(topic, payload, retain=retain)
