// Eclipse Tahu's Sparkplug B payload library (sparkplug-payload from npm) and the mqtt client
// from npm as a host application, for tests/sparkplug/tahu_test.py: what a host built on Tahu
// (Ignition's and most host libraries descend from it) reads of ioportd, and what it sends.
//
//     node host.js BROKER_PORT
//
// stdout: a JSON line per message on spBv1.0/#, {"topic", "payload"} as Tahu decodes it (64-bit
// integers as decimal strings, bytes as hex), or {"topic", "error"} when Tahu cannot; and
// {"subscribed": true} once the subscription holds. stdin: a JSON line {"topic", "payload"}
// per command to send, encoded by Tahu.
"use strict";
const mqtt = require("mqtt");
const readline = require("readline");
const sparkplug = require("sparkplug-payload").get("spBv1.0");
const {Payload} = require("sparkplug-payload/lib/sparkplugPayloadProto").org.eclipse.tahu.protobuf;

const port = Number(process.argv[2]);
if (!Number.isInteger(port) || port <= 0 || port > 65535) {
    console.error("usage: node host.js BROKER_PORT");
    process.exit(2);
}

// protobufjs hands 64-bit integers over as Long objects ({low, high, unsigned}).
function plain(key, value) {
    if (value && typeof value === "object" && typeof value.low === "number" &&
        typeof value.high === "number" && typeof value.unsigned === "boolean") {
        const high = BigInt(value.high >>> 0) << 32n;
        const both = high | BigInt(value.low >>> 0);
        return (value.unsigned ? both : BigInt.asIntN(64, both)).toString();
    }
    if (value instanceof Uint8Array) return Buffer.from(value).toString("hex");
    return value;
}

function print(object) {
    process.stdout.write(JSON.stringify(object, plain) + "\n");
}

const client = mqtt.connect(`mqtt://127.0.0.1:${port}`,
                            {clientId: `tahu-host-${process.pid}`, clean: true,
                             reconnectPeriod: 200, connectTimeout: 5000});
client.on("connect", () => {
    client.subscribe("spBv1.0/#", {qos: 0}, (error) => {
        if (error) {
            console.error(`subscribe: ${error.message}`);
            process.exit(1);
        }
        print({subscribed: true});
    });
});
// Sparkplug 3.0 leaves the datatype out of a DATA message's metrics, and of a template
// instance's members (the definition has them): only the births say. Tahu's decodePayload, which
// knows no births, returns null for such a value. A host keeps each node's and device's births
// and gives a DATA metric its birth's datatype (by alias, or by name), and a member its
// definition's, before Tahu decodes it.
const TEMPLATE = 19;
const births = new Map();       // "group/node[/device]" -> Map(alias or name -> metric's birth)
const definitions = new Map();  // "group/node/type" -> Map(member name -> datatype)
function key(metric) {
    // protobufjs puts a field's default on the prototype: own means on the wire.
    if (metric.name) return `name ${metric.name}`;
    return Object.prototype.hasOwnProperty.call(metric, "alias") ? `alias ${metric.alias}` : null;
}
function withBirthTypes(topic, message) {
    const [, group, kind, node, device] = topic.split("/");
    const source = [group, node, device].filter((part) => part !== undefined).join("/");
    const payload = Payload.decode(message);
    if (kind === "NBIRTH" || kind === "DBIRTH") {
        const metrics = new Map();
        for (const metric of payload.metrics) {
            const birth = {datatype: metric.datatype, templateRef: metric.templateValue?.templateRef};
            if (metric.name) metrics.set(`name ${metric.name}`, birth);
            if (Object.prototype.hasOwnProperty.call(metric, "alias"))
                metrics.set(`alias ${metric.alias}`, birth);
            if (metric.datatype === TEMPLATE && metric.templateValue?.isDefinition) {
                const type = metric.name.replace(/^_types_\//, "");
                definitions.set(`${group}/${node}/${type}`, new Map(
                    metric.templateValue.metrics.map((member) => [member.name, member.datatype])));
            }
        }
        births.set(source, metrics);
        return message;
    }
    const known = births.get(source);
    if (!known || (kind !== "NDATA" && kind !== "DDATA")) return message;
    for (const metric of payload.metrics) {
        const birth = known.get(key(metric));
        if (!birth) continue;
        if (!metric.datatype) metric.datatype = birth.datatype;
        const members = definitions.get(`${group}/${node}/${birth.templateRef}`);
        if (metric.datatype !== TEMPLATE || !members || !metric.templateValue) continue;
        for (const member of metric.templateValue.metrics)
            if (!member.datatype) member.datatype = members.get(member.name) ?? 0;
    }
    return Payload.encode(payload).finish();
}

client.on("message", (topic, message) => {
    try {
        print({topic, payload: sparkplug.decodePayload(withBirthTypes(topic, message))});
    } catch (error) {
        print({topic, error: String(error)});
    }
});
client.on("error", (error) => console.error(`mqtt: ${error.message}`));

readline.createInterface({input: process.stdin}).on("line", (line) => {
    const command = JSON.parse(line);
    client.publish(command.topic, Buffer.from(sparkplug.encodePayload(command.payload)),
                   {qos: 0});
}).on("close", () => client.end(true, () => process.exit(0)));
