"""Node-RED, from the npm registry, as a real consumer of ioportd's plain MQTT output.

    python3 node_red.py install DIR   # npm ci of tests/mqtt_json/node-red/ into DIR (once per
                                      # lock file: DIR keeps a copy and is left alone after)
    with NodeRed(DIR, workdir, broker_port, state_topic, set_topic, bridge):
        ...                           # a flow: state_topic's in0 drives set_topic (ON/OFF);
                                      # another: a transaction published on ASK is asked as
                                      # bridge/request/health_check, and the answer that echoes
                                      # it comes out on ANSWER (`bridge`: <prefix>/bridge)
"""
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))

import npm  # noqa: E402
from rig import die_with_parent, eventually, free_port  # noqa: E402

# The test's side of the health check flow: a transaction to ask with, the answer Node-RED
# matched to it.
ASK = "test/node-red/ask"
ANSWER = "test/node-red/answer"


def install(directory):
    npm.install(os.path.join(HERE, "node-red"), directory,
                os.path.join("node_modules", "node-red", "red.js"))


def flow(broker_port, state_topic, set_topic, bridge):
    """An interlock as a plant would wire it: in0 of a dim16 drives out7 of a dom16. And a
    health check as a zigbee2mqtt flow makes one: a request with a transaction, and the response
    that carries it back matched to the question (an answer to anybody else's is not taken)."""
    return [
        {"id": "tab", "type": "tab", "label": "ioportd"},
        {"id": "broker", "type": "mqtt-broker", "name": "ioportd's broker",
         "broker": "127.0.0.1", "port": str(broker_port), "clientid": "node-red-test",
         "autoConnect": True, "usetls": False, "protocolVersion": "4", "keepalive": "15",
         "cleansession": True},
        {"id": "state", "type": "mqtt in", "z": "tab", "name": "dim16_0 state",
         "topic": state_topic, "qos": "1", "datatype": "json", "broker": "broker",
         "nl": False, "rap": True, "rh": 0, "inputs": 0, "wires": [["interlock"]]},
        {"id": "interlock", "type": "function", "z": "tab", "name": "in0 drives out7",
         "func": "if (typeof msg.payload.in0 !== 'boolean') return null;\n"
                 "return { payload: msg.payload.in0 ? 'ON' : 'OFF' };",
         "outputs": 1, "wires": [["set"]]},
        {"id": "set", "type": "mqtt out", "z": "tab", "name": "dom16_0 out7 set",
         "topic": set_topic, "qos": "1", "retain": "false", "broker": "broker", "wires": []},
        {"id": "ask", "type": "mqtt in", "z": "tab", "name": "the test's transaction",
         "topic": ASK, "qos": "1", "datatype": "utf8", "broker": "broker",
         "nl": False, "rap": False, "rh": 0, "inputs": 0, "wires": [["question"]]},
        {"id": "question", "type": "function", "z": "tab", "name": "ask with a transaction",
         "func": "const asked = flow.get('asked') || [];\n"
                 "asked.push(msg.payload);\n"
                 "flow.set('asked', asked.slice(-20));\n"
                 "return { payload: { transaction: msg.payload } };",
         "outputs": 1, "wires": [["request"]]},
        {"id": "request", "type": "mqtt out", "z": "tab", "name": "health_check request",
         "topic": f"{bridge}/request/health_check", "qos": "1", "retain": "false",
         "broker": "broker", "wires": []},
        {"id": "response", "type": "mqtt in", "z": "tab", "name": "health_check response",
         "topic": f"{bridge}/response/health_check", "qos": "1", "datatype": "json",
         "broker": "broker", "nl": False, "rap": False, "rh": 0, "inputs": 0,
         "wires": [["match"]]},
        {"id": "match", "type": "function", "z": "tab", "name": "the answer to our question",
         "func": "const asked = flow.get('asked') || [];\n"
                 "if (!msg.payload || !asked.includes(msg.payload.transaction)) return null;\n"
                 "return { payload: { answer: msg.payload } };",
         "outputs": 1, "wires": [["answer"]]},
        {"id": "answer", "type": "mqtt out", "z": "tab", "name": "to the test",
         "topic": ANSWER, "qos": "1", "retain": "false", "broker": "broker", "wires": []},
    ]


class NodeRed:
    def __init__(self, directory, workdir, broker_port, state_topic, set_topic, bridge):
        self.red = os.path.join(directory, "node_modules", "node-red", "red.js")
        self.user_dir = os.path.join(workdir, "node-red-user")
        os.makedirs(self.user_dir, exist_ok=True)
        self.flows = os.path.join(self.user_dir, "flows.json")
        with open(self.flows, "w") as f:
            json.dump(flow(broker_port, state_topic, set_topic, bridge), f)
        self.port = free_port()
        self.log = os.path.join(workdir, "node-red.log")
        self.process = None

    def log_text(self):
        with open(self.log) as f:
            return f.read()

    def __enter__(self):
        with open(self.log, "w") as log:
            # Its editor and admin API on a loopback port of its own; no telemetry, no projects.
            self.process = subprocess.Popen(
                ["node", self.red, "--userDir", self.user_dir, "--port", str(self.port),
                 "--settings", os.path.join(HERE, "node_red_settings.js"), self.flows],
                stdout=log, stderr=log, preexec_fn=die_with_parent)

        def connected():
            assert self.process.poll() is None, self.log_text()
            return "Connected to broker" in self.log_text()
        eventually(connected, 60, lambda: "Node-RED connected to the broker:\n" +
                   self.log_text()[-3000:])
        return self

    def __exit__(self, *_):
        self.process.terminate()
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(5)


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "install":
        sys.exit("usage: node_red.py install DIR")
    install(sys.argv[2])
