"""A Sparkplug B 3.0 host application for the tests: it watches spBv1.0/#, decodes every
message, keeps the view a SCADA host would keep of every edge node, and checks the rules of the
specification that an edge node must keep. A broken rule is recorded in `violations` (never
skipped, never raised in the MQTT thread): a test asserts the list is empty at its end.

The rules are in RULES below, each with the Sparkplug 3.0 TCK ids (docs/sparkplug-conformance.md)
or the gateway.md section it checks; a violation names its rule. What the broker sees and does
not forward (the CONNECT, the will, SUBSCRIBE, each PUBLISH's QoS and retain flag) is checked by
BrokerLog on mosquitto's own log. The host app's own (re)connection to the broker forgets every
node: it may have missed messages, so the next message from each node must be an NBIRTH again
(which is what a node does after a broker restart).

It can publish NCMD rebirth, DCMD (by name or alias, typed) and STATE for a primary host id, and
wait (with a deadline, by polling its record under a condition variable) for a message type,
device or metric value.
"""
import json
import re
import struct
import threading
import time

import paho.mqtt.client as mqtt

import sparkplug_b_pb2 as pb

PREFIX = "spBv1.0"

# rule -> (what it checks, the TCK ids it covers or the contract's section). Checked on every
# message of every test: each test ends by asserting `violations` is empty.
RULES = {
    "births first": (
        "nothing but NBIRTH from a node not born in this session (no NDATA, DBIRTH, DDATA, "
        "DDEATH before it); no DDATA or DDEATH of a device before its DBIRTH; a DBIRTH's group "
        "and node are those of the NBIRTH",
        ["tck-id-principles-birth-certificates-order", "tck-id-payloads-ndata-order",
         "tck-id-payloads-ddata-order", "tck-id-message-flow-device-birth-publish-nbirth-wait",
         "tck-id-message-flow-device-birth-publish-dbirth-match-edge-node-topic"]),
    "topic": (
        "every topic is `spBv1.0/<group>/<type>/<node>[/<device>]`, the device id present "
        "exactly for DBIRTH, DDATA, DDEATH",
        ["tck-id-topics-nbirth-topic", "tck-id-topics-dbirth-topic",
         "tck-id-message-flow-edge-node-birth-publish-nbirth-topic",
         "tck-id-message-flow-device-birth-publish-dbirth-topic", "tck-id-topics-ndata-topic",
         "tck-id-topics-ddata-topic", "tck-id-topics-ddeath-topic"]),
    "decodes": (
        "every payload decodes as a Sparkplug B protobuf Payload",
        ["tck-id-message-flow-edge-node-birth-publish-nbirth-payload",
         "tck-id-message-flow-device-birth-publish-dbirth-payload",
         "tck-id-payloads-metric-datatype-value-type"]),
    "timestamp": (
        "every payload but NCMD/DCMD has a timestamp",
        ["tck-id-payloads-nbirth-timestamp", "tck-id-topics-nbirth-timestamp",
         "tck-id-topics-dbirth-timestamp", "tck-id-payloads-dbirth-timestamp",
         "tck-id-payloads-ddeath-timestamp", "tck-id-topics-ndata-timestamp",
         "tck-id-topics-ddata-timestamp", "tck-id-payloads-ndata-timestamp",
         "tck-id-payloads-ddata-timestamp"]),
    "metric timestamp": (
        "every metric of NBIRTH, DBIRTH, NDATA and DDATA has a timestamp",
        ["tck-id-payloads-name-birth-data-requirement"]),
    "utc": (
        "timestamps are UTC milliseconds: never more than 5 s ahead of the host's clock, and "
        "current ones (not NDEATH's, made at CONNECT; not history) within 60 s of it",
        ["tck-id-payloads-metric-timestamp-in-UTC"]),
    "nbirth": (
        "NBIRTH: seq 0, a bdSeq metric, Node Control/Rebirth with no alias; a new NBIRTH only "
        "after the previous session's NDEATH",
        ["tck-id-payloads-nbirth-seq", "tck-id-payloads-sequence-num-req-nbirth",
         "tck-id-topics-nbirth-seq-num",
         "tck-id-message-flow-edge-node-birth-publish-nbirth-payload-seq",
         "tck-id-payloads-nbirth-bdseq", "tck-id-topics-nbirth-bdseq-included",
         "tck-id-payloads-nbirth-rebirth-req", "tck-id-topics-nbirth-rebirth-metric",
         "tck-id-operational-behavior-data-commands-rebirth-name",
         "tck-id-operational-behavior-data-commands-rebirth-name-aliases"]),
    "seq": (
        "every message of a born node but NDEATH has seq, one more (mod 256) than the last",
        ["tck-id-payloads-sequence-num-always-included", "tck-id-payloads-dbirth-seq",
         "tck-id-topics-dbirth-seq", "tck-id-payloads-dbirth-seq-inc",
         "tck-id-topics-ddeath-seq-num", "tck-id-payloads-ddeath-seq",
         "tck-id-payloads-ddeath-seq-inc", "tck-id-payloads-ddeath-seq-number",
         "tck-id-topics-ndata-seq-num", "tck-id-payloads-ndata-seq",
         "tck-id-topics-ddata-seq-num", "tck-id-payloads-ddata-seq"]),
    "ndeath": (
        "NDEATH: no seq, one metric, bdSeq, equal to the bdSeq of the session's NBIRTH",
        ["tck-id-payloads-ndeath-seq", "tck-id-topics-ndeath-seq", "tck-id-topics-ndeath-payload",
         "tck-id-payloads-ndeath-bdseq"]),
    "birth metrics": (
        "every birth metric has a name, a datatype of the enumeration (not Unknown), and a value "
        "or is_null, never both; an alias only with a name",
        ["tck-id-topics-nbirth-metrics", "tck-id-topics-dbirth-metrics",
         "tck-id-payloads-metric-datatype-req", "tck-id-payloads-metric-datatype-value",
         "tck-id-payloads-alias-birth-requirement",
         "tck-id-operational-behavior-data-publish-nbirth-values"]),
    "names": (
        "metric names are unique in a birth, also when lower-cased",
        ["tck-id-case-sensitivity-metric-names"]),
    "aliases": (
        "aliases are unique across the node: its own metrics and every device's",
        ["tck-id-payloads-alias-uniqueness"]),
    "data announced": (
        "every NDATA/DDATA metric was announced in the session's birth (by alias, or by name "
        "where the birth gave none)",
        ["tck-id-payloads-name-requirement"]),
    "data by alias": (
        "an NDATA/DDATA metric whose birth gave it an alias goes by the alias alone",
        ["tck-id-payloads-alias-data-cmd-requirement"]),
    "data datatype": (
        "NDATA/DDATA metrics leave the datatype to the birth",
        ["tck-id-payloads-metric-datatype-not-req"]),
    "on change": (
        "a current NDATA/DDATA metric carries a value other than the last known (data only on "
        "change), once in a message",
        ["gateway.md §5.5"]),
    "historical": (
        "a metric marked is_historical has its acquisition timestamp; it is history and changes "
        "neither the host's view nor counts as data on change",
        ["gateway.md §6.2"]),
    "properties": (
        "a metric's PropertySet has as many values as keys, and every PropertyValue has a type "
        "of the basic or property value data types whose value field it fills",
        ["tck-id-payloads-propertyset-keys-array-size",
         "tck-id-payloads-propertyset-values-array-size",
         "tck-id-payloads-metric-propertyvalue-type-type",
         "tck-id-payloads-metric-propertyvalue-type-value",
         "tck-id-payloads-metric-propertyvalue-type-req"]),
    "template definitions": (
        "a Template metric that is a definition is in NBIRTH only, has is_definition true and no "
        "template_ref, a version (a string) if any, members with names and datatypes, and "
        "parameters with names and types",
        ["tck-id-payloads-template-definition-nbirth-only",
         "tck-id-payloads-template-definition-ref", "tck-id-payloads-template-ref-definition",
         "tck-id-payloads-template-definition-is-definition",
         "tck-id-payloads-template-is-definition-definition",
         "tck-id-payloads-template-is-definition", "tck-id-payloads-template-version"]),
    "template instances": (
        "every other Template metric is an instance: is_definition present and false, a "
        "template_ref naming a definition of the session's NBIRTH; in a birth, every member of "
        "that definition with its datatype; anywhere, only members and parameters of it",
        ["tck-id-payloads-template-instance-is-definition",
         "tck-id-payloads-template-is-definition-instance",
         "tck-id-payloads-template-is-definition", "tck-id-payloads-template-instance-ref",
         "tck-id-payloads-template-ref-instance", "tck-id-payloads-template-definition-nbirth",
         "tck-id-payloads-template-instance-members-birth",
         "tck-id-payloads-template-instance-members",
         "tck-id-payloads-template-definition-members",
         "tck-id-payloads-template-definition-parameters"]),
    "host app": ("the host app itself did not fail on a message", []),
    # BrokerLog: what mosquitto saw of the node's client.
    "connect": (
        "the node connects with MQTT 5 and Clean Start, or with MQTT 3.1.1 and Clean Session to "
        "a broker that refuses 5 (the Session Expiry Interval 0 of MQTT 5, which the broker does "
        "not log, is read from the CONNECT by `Lifecycle.test_a_broker_without_mqtt5_is_spoken_"
        "to_in_3_1_1`)",
        ["tck-id-principles-persistence-clean-session-311",
         "tck-id-principles-persistence-clean-session-50"]),
    "will": (
        "every CONNECT registers a will: QoS 1, not retained, on `spBv1.0/<group>/NDEATH/<node>`",
        ["tck-id-payloads-ndeath-will-message-qos", "tck-id-payloads-ndeath-will-message-retain",
         "tck-id-message-flow-edge-node-birth-publish-will-message-qos",
         "tck-id-message-flow-edge-node-birth-publish-will-message-will-retained",
         "tck-id-message-flow-edge-node-birth-publish-will-message-topic"]),
    "subscriptions": (
        "before its NBIRTH in a connection the node subscribed to `spBv1.0/<group>/NCMD/<node>` "
        "and `spBv1.0/<group>/DCMD/<node>/+` (and, with a primary host, `spBv1.0/STATE/<id>`) "
        "at QoS 1",
        ["tck-id-message-flow-edge-node-ncmd-subscribe",
         "tck-id-message-flow-device-dcmd-subscribe",
         "tck-id-operational-behavior-primary-application-state-with-multiple-servers-state-subs"]),
    "publish flags": (
        "NBIRTH, DBIRTH, NDATA, DDATA and DDEATH are published at QoS 0, NDEATH at QoS 1, none "
        "retained, and only within a connection the broker accepted",
        ["tck-id-payloads-nbirth-qos", "tck-id-payloads-nbirth-retain",
         "tck-id-topics-nbirth-mqtt",
         "tck-id-message-flow-edge-node-birth-publish-nbirth-qos",
         "tck-id-message-flow-edge-node-birth-publish-nbirth-retained",
         "tck-id-message-flow-edge-node-birth-publish-connect",
         "tck-id-payloads-dbirth-qos", "tck-id-payloads-dbirth-retain",
         "tck-id-topics-dbirth-mqtt", "tck-id-message-flow-device-birth-publish-dbirth-qos",
         "tck-id-message-flow-device-birth-publish-dbirth-retained", "tck-id-topics-ddeath-mqtt",
         "tck-id-topics-ndata-mqtt", "tck-id-payloads-ndata-qos", "tck-id-payloads-ndata-retain",
         "tck-id-topics-ddata-mqtt", "tck-id-payloads-ddata-qos",
         "tck-id-payloads-ddata-retain"]),
}
NODE_TYPES = {"NBIRTH", "NDEATH", "NDATA", "NCMD"}
DEVICE_TYPES = {"DBIRTH", "DDEATH", "DDATA", "DCMD"}

# Sparkplug 3.0 §6.4.16
DATATYPES = {name: number for number, name in enumerate(
    ["Unknown", "Int8", "Int16", "Int32", "Int64", "UInt8", "UInt16", "UInt32", "UInt64", "Float",
     "Double", "Boolean", "String", "DateTime", "Text", "UUID", "DataSet", "Bytes", "File",
     "Template"])}
TYPE_NAMES = {number: name for name, number in DATATYPES.items()}
INT_TYPES = {"Int8", "Int16", "Int32", "UInt8", "UInt16", "UInt32"}
# Sparkplug 3.0 §6.4.17: what a PropertyValue may be, and the field each type fills.
PROPERTY_FIELDS = {**{DATATYPES[t]: "int_value" for t in INT_TYPES},
                   **{DATATYPES[t]: "long_value" for t in ("Int64", "UInt64", "DateTime")},
                   DATATYPES["Float"]: "float_value", DATATYPES["Double"]: "double_value",
                   DATATYPES["Boolean"]: "boolean_value", DATATYPES["String"]: "string_value",
                   DATATYPES["Text"]: "string_value", 20: "propertyset_value",
                   21: "propertysets_value"}
LONG_TYPES = {"Int64", "UInt64", "DateTime"}


class Template:
    """A decoded Template (Sparkplug 3.0 §6.4.14): None for the fields that are absent."""

    def __init__(self, version, ref, is_definition, members, parameters):
        self.version, self.ref, self.is_definition = version, ref, is_definition
        self.members = members  # [Metric]
        self.parameters = parameters  # [(name or None, type or None)]

    def __repr__(self):
        kind = "definition" if self.is_definition else f"instance of {self.ref}"
        return f"Template({kind}, {self.members})"


class Metric:
    """A decoded metric: value None for is_null; `template` the Template of a Template metric."""

    def __init__(self, name, alias, datatype, value, timestamp, is_historical=False,
                 is_null=False, has_value=True, properties=None, template=None):
        self.name, self.alias, self.datatype, self.value = name, alias, datatype, value
        self.timestamp, self.is_historical = timestamp, is_historical
        self.is_null, self.has_value = is_null, has_value
        self.properties = properties or {}  # key -> value
        self.template = template

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
    if kind is None or kind == "template_value":
        return None
    return getattr(metric, kind)


def decode_metric(m):
    """A protobuf metric as a Metric, a Template's members decoded alike."""
    template = None
    if m.WhichOneof("value") == "template_value":
        t = m.template_value
        template = Template(
            t.version if t.HasField("version") else None,
            t.template_ref if t.HasField("template_ref") else None,
            t.is_definition if t.HasField("is_definition") else None,
            [decode_metric(member) for member in t.metrics],
            [(p.name if p.HasField("name") else None, p.type if p.HasField("type") else None)
             for p in t.parameters])
    return Metric(m.name if m.HasField("name") else None, m.alias if m.HasField("alias") else None,
                  m.datatype if m.HasField("datatype") else None, decode_value(m),
                  m.timestamp if m.HasField("timestamp") else None,
                  m.HasField("is_historical") and m.is_historical,
                  m.HasField("is_null") and m.is_null, m.WhichOneof("value") is not None,
                  {k: getattr(v, v.WhichOneof("value") or "is_null")
                   for k, v in zip(m.properties.keys, m.properties.values)}, template)


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
        # NBIRTH's template definitions, by the name an instance's template_ref gives:
        # name -> ({member: datatype}, {parameter names})
        self.templates = {}


class HostApp:
    def __init__(self, port, host="127.0.0.1", client_id="ioportd-test-host", keep_session=False,
                 credentials=None):
        """keep_session: a persistent session (Clean Session 0), for a broker that keeps it over
        a restart (Broker(keep_sessions=True)); credentials: (user name, password), for a broker
        that wants them (ejabberd's mod_mqtt, tests/support/cluster.py)."""
        self.violations = []
        self.messages = []
        self.nodes = {}
        self.connects = 0
        self._cond = threading.Condition()
        self._client = mqtt.Client(client_id=client_id, clean_session=not keep_session,
                                   protocol=mqtt.MQTTv311)
        if credentials:
            self._client.username_pw_set(*credentials)
        self._client.on_connect = self._on_connect
        self._client.on_message = self._on_message
        # Back soon after a broker restart; what comes before waits only if keep_session.
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

    def violation(self, message, rule, text):
        assert rule in RULES, rule
        where = f"{message!r}: " if message else ""
        self.violations.append(f"[{rule}] {where}{text}")

    def _on_message(self, client, userdata, msg):
        try:
            with self._cond:
                self._receive(msg.topic, msg.payload)
                self._cond.notify_all()
        except Exception as e:  # a bug here must show up, not vanish in paho's thread
            with self._cond:
                self.violation(None, "host app", f"error on {msg.topic}: {e!r}")
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
            self.violation(None, "topic", f"topic outside the Sparkplug namespace: {topic}")
            return
        group, type_, node = parts[1], parts[2], parts[3]
        device = parts[4] if len(parts) == 5 else None
        message = Message(index, time.monotonic(), topic, type_, group, node, device, payload)
        self.messages.append(message)
        if type_ not in NODE_TYPES | DEVICE_TYPES:
            self.violation(message, "topic", f"unknown message type {type_}")
            return
        if (type_ in DEVICE_TYPES) != (device is not None):
            self.violation(message, "topic", "device id present/absent against the message type")
            return
        decoded = pb.Payload()
        try:
            decoded.ParseFromString(payload)
        except Exception as e:
            self.violation(message, "decodes", f"payload does not decode: {e}")
            return
        message.seq = decoded.seq if decoded.HasField("seq") else None
        message.timestamp = decoded.timestamp if decoded.HasField("timestamp") else None
        message.metrics = [decode_metric(m) for m in decoded.metrics]

        def properties(metrics):
            for m in metrics:
                if m.HasField("properties"):
                    self._check_properties(message, m)
                if m.WhichOneof("value") == "template_value":
                    properties(m.template_value.metrics)
        properties(decoded.metrics)
        if type_ in ("NCMD", "DCMD"):
            return  # commands: ours, or another host's; not the node's to keep rules on
        if message.timestamp is None:
            self.violation(message, "timestamp", "payload without timestamp")
        self._check_times(message)
        state = self.nodes.setdefault((group, node), NodeState())
        getattr(self, "_" + type_.lower())(state, message)
        self._check_templates(state, message)

    def _check_templates(self, state, message):
        """The template rules (Sparkplug 3.0 §6.4.14) on every Template metric of a message."""
        birth = message.type in ("NBIRTH", "DBIRTH")
        for m in message.metrics:
            t = m.template
            if t is None:
                continue
            what = m.name or f"alias {m.alias}"
            if t.is_definition:
                rule = "template definitions"
                if message.type != "NBIRTH":
                    self.violation(message, rule, f"{what}: a definition in {message.type}")
                if t.ref is not None:
                    self.violation(message, rule, f"{what}: a definition with template_ref "
                                                  f"{t.ref!r}")
                if t.version is not None and not isinstance(t.version, str):
                    self.violation(message, rule, f"{what}: version {t.version!r}")
                for member in t.members:
                    if not member.name or member.datatype is None:
                        self.violation(message, rule, f"{what}: member {member!r} without a "
                                                      f"name or datatype")
                for name, type_ in t.parameters:
                    if name is None or type_ is None:
                        self.violation(message, rule, f"{what}: a parameter without a name or "
                                                      f"type")
                continue
            rule = "template instances"
            if t.is_definition is None:
                self.violation(message, rule, f"{what}: a Template without is_definition")
            if t.ref is None:
                self.violation(message, rule, f"{what}: an instance without template_ref")
                continue
            if t.ref not in state.templates:
                self.violation(message, rule, f"{what}: template_ref {t.ref} is no definition of "
                                              f"the NBIRTH ({sorted(state.templates)})")
                continue
            members, parameters = state.templates[t.ref]
            got = {member.name: member.datatype for member in t.members}
            extra = [name for name in got if name not in members]
            if extra:
                self.violation(message, rule, f"{what}: members {extra} are not in {t.ref}")
            if birth and got != members:
                self.violation(message, rule, f"{what}: in a birth, members {got} are not "
                                              f"{t.ref}'s {members}")
            unknown = [name for name, _ in t.parameters if name not in parameters]
            if unknown:
                self.violation(message, rule, f"{what}: parameters {unknown} are not {t.ref}'s")

    def _check_properties(self, message, metric):
        keys, values = metric.properties.keys, metric.properties.values
        if len(keys) != len(values):
            self.violation(message, "properties",
                           f"{metric.name or metric.alias}: {len(keys)} keys, {len(values)} values")
        for key, value in zip(keys, values):
            field = PROPERTY_FIELDS.get(value.type) if value.HasField("type") else None
            if field is None:
                self.violation(message, "properties", f"{metric.name or metric.alias}: property "
                               f"{key!r} has no valid type ({value.type})")
            elif not (value.HasField("is_null") and value.is_null) and \
                    value.WhichOneof("value") != field:
                self.violation(message, "properties", f"{metric.name or metric.alias}: property "
                               f"{key!r} of type {value.type} fills {value.WhichOneof('value')}")

    def _check_times(self, message):
        now = time.time() * 1000
        current = message.type != "NDEATH"  # the will's payload was made at CONNECT
        stamps = [(message.timestamp, current, "payload")] + [
            (m.timestamp, current and not m.is_historical, m.name or m.alias)
            for m in message.metrics]
        for stamp, live, what in stamps:
            if stamp is not None and (stamp > now + 5000 or (live and stamp < now - 60000)):
                self.violation(message, "utc",
                               f"{what}: timestamp {stamp} is not UTC ms (host: {now:.0f})")
        if message.type in ("NBIRTH", "DBIRTH", "NDATA", "DDATA"):
            for m in message.metrics:
                if m.timestamp is None:
                    self.violation(message, "metric timestamp", f"{m!r} without timestamp")

    def _check_seq(self, state, message):
        if message.seq is None:
            self.violation(message, "seq", "no seq")
            return
        if not 0 <= message.seq <= 255:
            self.violation(message, "seq", f"seq {message.seq} outside 0..255")
        if state.last_seq is not None and message.seq != (state.last_seq + 1) % 256:
            self.violation(message, "seq", f"seq {message.seq} after {state.last_seq}")
        state.last_seq = message.seq

    def _announce(self, state, device_state, message, owner):
        """The metrics of a birth: names unique in it, aliases unique across the node."""
        device_state.by_alias, device_state.by_name, device_state.values = {}, {}, {}
        taken = {}
        taken.update({a: "node" for a in state.node_metrics.by_alias} if owner != "node" else {})
        for device_id, other in state.devices.items():
            if device_id != owner:
                taken.update({a: device_id for a in other.by_alias})
        folded = {}
        for m in message.metrics:
            if not m.name:
                self.violation(message, "birth metrics", f"birth metric without a name: {m!r}")
                continue
            if m.name.lower() in folded:
                self.violation(message, "names", f"metric {m.name} after "
                                                 f"{folded[m.name.lower()]} in one birth")
            folded[m.name.lower()] = m.name
            if m.datatype is None:
                self.violation(message, "birth metrics", f"birth metric {m.name} without datatype")
            elif m.datatype not in TYPE_NAMES or m.datatype == DATATYPES["Unknown"]:
                self.violation(message, "birth metrics",
                               f"birth metric {m.name}: datatype {m.datatype} is none of §6.4.16")
            if m.is_null == m.has_value:
                self.violation(message, "birth metrics",
                               f"birth metric {m.name}: is_null {m.is_null} with "
                               f"{'a' if m.has_value else 'no'} value")
            if m.alias is not None:
                if m.alias in device_state.by_alias:
                    self.violation(message, "aliases", f"alias {m.alias} twice in one birth")
                if m.alias in taken:
                    self.violation(message, "aliases",
                                   f"alias {m.alias} of {m.name} is already {taken[m.alias]}'s")
                device_state.by_alias[m.alias] = (m.name, m.datatype)
            device_state.by_name[m.name] = (m.alias, m.datatype)
            if m.template is not None and not m.template.is_definition:
                # An instance: the host's view is of its members, "<instance>/<member>", as
                # Ignition's tag browser shows them.
                for member in m.template.members:
                    path = f"{m.name}/{member.name}"
                    device_state.values[path] = member.value
                    message.resolved[path] = member.value
                continue
            device_state.values[m.name] = m.value
            message.resolved[m.name] = m.value

    def _data(self, device_state, message):
        seen = set()
        for m in message.metrics:
            if m.alias is not None and m.alias in device_state.by_alias:
                name, datatype = device_state.by_alias[m.alias]
                if m.name:
                    self.violation(message, "data by alias",
                                   f"alias {m.alias} ({name}) with a name, {m.name}")
            elif m.name and m.name in device_state.by_name:
                name, (alias, datatype) = m.name, device_state.by_name[m.name]
                if alias is not None:
                    self.violation(message, "data by alias", f"{name} by name, not alias {alias}")
            else:
                self.violation(message, "data announced",
                               f"metric not announced in the birth: {m!r}")
                continue
            if m.datatype is not None:
                self.violation(message, "data datatype", f"{name}: datatype {m.datatype} in DATA")
            if m.template is not None:
                self._data_instance(device_state, message, name, m, seen)
                continue
            if m.is_historical:
                # A stored value (store-and-forward): history, not the current state, so it
                # neither changes the view nor counts as data on change.
                if m.timestamp is None:
                    self.violation(message, "historical", f"historical {name} without timestamp")
                message.historical.append((name, m.value, m.timestamp))
                continue
            if name in seen:
                self.violation(message, "on change", f"{name} twice in one message")
            seen.add(name)
            if same_value(device_state.values.get(name), m.value, datatype):
                self.violation(message, "on change",
                               f"{name} = {m.value!r} unchanged: data only on change")
            device_state.values[name] = m.value
            message.resolved[name] = m.value

    def _data_instance(self, device_state, message, name, instance, seen):
        """The members of an instance in DATA, by "<instance>/<member>": only those that
        changed (or history, when the instance or the member says so)."""
        for m in instance.template.members:
            path = f"{name}/{m.name}"
            if m.datatype is not None:
                self.violation(message, "data datatype", f"{path}: datatype {m.datatype} in DATA")
            if instance.is_historical or m.is_historical:
                if m.timestamp is None and instance.timestamp is None:
                    self.violation(message, "historical", f"historical {path} without timestamp")
                message.historical.append((path, m.value, m.timestamp or instance.timestamp))
                continue
            if path in seen:
                self.violation(message, "on change", f"{path} twice in one message")
            seen.add(path)
            if same_value(device_state.values.get(path), m.value, self._member_type(
                    message, instance.template.ref, m.name)):
                self.violation(message, "on change",
                               f"{path} = {m.value!r} unchanged: data only on change")
            device_state.values[path] = m.value
            message.resolved[path] = m.value

    def _member_type(self, message, ref, member):
        state = self.nodes.get((message.group, message.node))
        members = state.templates.get(ref, ({}, set()))[0] if state else {}
        return members.get(member)

    def _nbirth(self, state, message):
        if message.seq != 0:
            self.violation(message, "nbirth", f"NBIRTH seq {message.seq}, not 0")
        bdseq = message.metric("bdSeq")
        if bdseq is None or bdseq.value is None:
            self.violation(message, "nbirth", "NBIRTH without bdSeq")
        rebirth = message.metric("Node Control/Rebirth")
        if rebirth is None:
            self.violation(message, "nbirth", "NBIRTH without Node Control/Rebirth")
        elif rebirth.alias is not None:
            self.violation(message, "nbirth", f"Node Control/Rebirth with alias {rebirth.alias}")
        if state.born and bdseq is not None and bdseq.value != state.bdseq:
            # A new session without the old one's NDEATH: only if the old connection was lost
            # where the host could not see it, which the host's reconnect would have cleared.
            self.violation(message, "nbirth", f"NBIRTH bdSeq {bdseq.value} while the session of "
                                              f"bdSeq {state.bdseq} had no NDEATH")
        state.born = True
        state.sessions += 1
        state.bdseq = bdseq.value if bdseq is not None else None
        state.last_seq = message.seq
        state.devices = {}
        state.node_metrics = DeviceState()
        state.node_metrics.born = True
        # Named "_types_/<name>" (as Ignition and Eclipse Tahu name them), referred to as <name>.
        state.templates = {
            m.name.removeprefix("_types_/"): (
                {member.name: member.datatype for member in m.template.members},
                     {name for name, _ in m.template.parameters})
            for m in message.metrics if m.template is not None and m.template.is_definition}
        self._announce(state, state.node_metrics, message, "node")

    def _ndeath(self, state, message):
        if message.seq is not None:
            self.violation(message, "ndeath", f"NDEATH with seq {message.seq}")
        if len(message.metrics) != 1:
            self.violation(message, "ndeath", f"NDEATH with {len(message.metrics)} metrics, not 1")
        bdseq = message.metric("bdSeq")
        if bdseq is None:
            self.violation(message, "ndeath", "NDEATH without bdSeq")
        elif state.born and bdseq.value != state.bdseq:
            self.violation(message, "ndeath", f"NDEATH bdSeq {bdseq.value} ends the session of "
                                              f"NBIRTH bdSeq {state.bdseq}")
        state.born = False
        state.last_seq = None
        for device in state.devices.values():
            device.born = False

    def _born_node(self, state, message):
        if not state.born:
            self.violation(message, "births first", f"{message.type} before NBIRTH")
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
            self.violation(message, "births first", "DDATA before the device's DBIRTH")
            return
        self._data(device, message)

    def _ddeath(self, state, message):
        if not self._born_node(state, message):
            return
        device = state.devices.get(message.device)
        if device is None or not device.born:
            self.violation(message, "births first", "DDEATH of a device not born")
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

    def dcmd_instance(self, group, node, device, instance, members, alias=None):
        """A DCMD as Ignition's MQTT Engine writes a UDT member: the device's template instance
        (by name, or by `alias`), datatype Template, template_ref the instance's type,
        is_definition false, holding `members` (name -> value), each typed as the NBIRTH's
        definition says."""
        with self._cond:
            definition = self.nodes[(group, node)].templates[instance][0] \
                if instance in self.nodes[(group, node)].templates else None
        payload = pb.Payload(timestamp=int(time.time() * 1000))
        m = payload.metrics.add()
        if alias is None:
            m.name = instance
        else:
            m.alias = alias
        m.datatype = DATATYPES["Template"]
        m.template_value.template_ref = instance
        m.template_value.is_definition = False
        for name, value in members.items():
            member = m.template_value.metrics.add(name=name)
            datatype = definition[name] if definition and name in definition else "Boolean"
            encode_value(member, datatype, value)
        self._publish(f"{PREFIX}/{group}/DCMD/{node}/{device}", payload.SerializeToString())

    def state(self, host_id, online, retain=True, timestamp=None):
        if timestamp is None:
            timestamp = int(time.time() * 1000)
        body = json.dumps({"online": online, "timestamp": timestamp})
        self._publish(f"{PREFIX}/STATE/{host_id}", body, qos=1, retain=retain)

    def publish_raw(self, topic, payload, retain=False):
        self._publish(topic, payload, retain=retain)


class BrokerLog:
    """What mosquitto (`log_type all`) saw of one client, the edge node, checked against the RULES
    of the broker's side: the CONNECT, the will, SUBSCRIBE, every PUBLISH's QoS and retain flag
    (facts the broker does not forward). check() reads what was logged since its last call."""

    LINE = re.compile(r"^\d+: (.*)$")
    CONNECTED = re.compile(r"New client connected from \S+ as (\S+) \(p(\d+), c(\d+), k\d+")
    WILL = re.compile(r"Will message specified \(\d+ bytes\) \(r(\d+), q(\d+)\)\.")
    SUBSCRIBE = re.compile(r"Received SUBSCRIBE from (\S+)$")
    FILTER = re.compile(r"^\t(\S+) \(QoS (\d+)\)$")
    PUBLISH = re.compile(r"Received PUBLISH from (\S+) \(d\d+, q(\d+), r(\d+), m\d+, '([^']*)'")
    GONE = re.compile(r"Client (\S+) (?:disconnected|closed its connection)|"
                      r"Socket error on client (\S+),|Client (\S+) has exceeded timeout")

    def __init__(self, path, client_id, group, node, primary_host=None):
        self.path, self.client_id = path, client_id
        self.group, self.node, self.primary_host = group, node, primary_host
        self.offset, self.rest = 0, ""
        self.connected, self.expect, self.filters = False, None, {}
        self.connects = self.publishes = 0  # for a test to see that there was something to check

    def check(self):
        with open(self.path, errors="replace") as f:
            f.seek(self.offset)
            text = self.rest + f.read()
            self.offset = f.tell()
        lines = text.split("\n")
        self.rest = lines.pop()
        found = []
        for line in lines:
            m = self.LINE.match(line)
            if m:
                self._line(m.group(1), found)
        return found

    def _line(self, line, found):
        def violation(rule, text):
            assert rule in RULES, rule
            found.append(f"[{rule}] broker log: {text}")
        expect, self.expect = self.expect, None
        if expect == "will topic":
            topic = f"{PREFIX}/{self.group}/NDEATH/{self.node}"
            if line != "\t" + topic:
                violation("will", f"the will's topic is {line.strip()!r}, not {topic}")
            return
        if expect == "filters" and (m := self.FILTER.match(line)):
            self.filters[m.group(1)] = int(m.group(2))
            self.expect = "filters"
            return
        if expect == "filters" and line.startswith(self.client_id + " "):
            self.expect = "filters"  # mosquitto's own "<client> <qos> <filter>" line
            return
        if expect == "will":
            m = self.WILL.match(line)
            if not m:
                violation("will", f"CONNECT of {self.client_id} without a will: {line!r}")
            elif (m.group(1), m.group(2)) != ("0", "1"):
                violation("will", f"the will is r{m.group(1)}, q{m.group(2)}, not r0, q1")
            else:
                self.expect = "will topic"
            return
        if (m := self.CONNECTED.match(line)) and m.group(1) == self.client_id:
            self.connects += 1
            self.connected, self.filters, self.expect = True, {}, "will"
            # mosquitto's p: 2 for MQTT 3.1.1, 5 for MQTT 5; c: Clean Session, or Clean Start
            if m.group(2) not in ("2", "5") or m.group(3) != "1":
                violation("connect", f"CONNECT p{m.group(2)}, c{m.group(3)}: neither MQTT 5 "
                                     f"with Clean Start nor MQTT 3.1.1 with Clean Session")
        elif (m := self.SUBSCRIBE.match(line)) and m.group(1) == self.client_id:
            self.expect = "filters"
        elif (m := self.PUBLISH.match(line)) and m.group(1) == self.client_id:
            self.publishes += 1
            self._publish(int(m.group(2)), int(m.group(3)), m.group(4), violation)
        elif (m := self.GONE.search(line)) and self.client_id in m.groups():
            self.connected = False

    def _publish(self, qos, retain, topic, violation):
        parts = topic.split("/")
        type_ = parts[2] if len(parts) > 2 else ""
        if not self.connected:
            violation("publish flags", f"PUBLISH {topic} outside an accepted connection")
        wanted = 1 if type_ == "NDEATH" else 0
        if qos != wanted or retain:
            violation("publish flags", f"{topic} at QoS {qos}, retain {retain}: not QoS {wanted}, "
                                       f"not retained")
        if type_ != "NBIRTH":
            return
        needed = [f"{PREFIX}/{self.group}/NCMD/{self.node}",
                  f"{PREFIX}/{self.group}/DCMD/{self.node}/+"]
        if self.primary_host:
            needed.append(f"{PREFIX}/STATE/{self.primary_host}")
        for pattern in needed:
            if self.filters.get(pattern) != 1:
                violation("subscriptions", f"NBIRTH before a QoS 1 subscription to {pattern} "
                                           f"(subscribed: {self.filters})")
