"""A real Mosquitto broker for the system tests: on a free loopback port, anonymous, logging
everything (tests/sparkplug/host_app.py's BrokerLog reads the log).

    broker = Broker(directory)
    broker.start()                # waits until it listens
    broker.stop(); broker.start() # the same port again

keep_sessions=True: the broker saves its clients' persistent sessions (Clean Session 0) when
stopped and keeps queueing for them, QoS 0 included, while they are away, so a subscriber that
reconnects after a restart misses nothing published after the broker came back, however soon.
"""

import getpass
import os
import socket
import subprocess
import time

from rig import SLOWDOWN, eventually, free_port


class Broker:
    """mosquitto on 127.0.0.1:port, anonymous, logging everything (BrokerLog); stop() and
    start() again on the same port."""

    def __init__(self, directory, port=None, keep_sessions=False):
        self.port = port or free_port()
        self.config = os.path.join(directory, "mosquitto.conf")
        self.log = os.path.join(directory, "mosquitto.log")
        with open(self.config, "w") as f:
            f.write(f"listener {self.port} 127.0.0.1\nallow_anonymous true\nlog_type all\n")
            if keep_sessions:
                # Run as root, mosquitto would otherwise become user mosquitto, who cannot
                # write its database into this directory.
                f.write(f"persistence true\npersistence_location {directory}/\n"
                        f"queue_qos0_messages true\nuser {getpass.getuser()}\n")
            else:
                f.write("persistence false\n")
        self.process = None

    def start(self):
        with open(self.log, "a") as log:
            self.process = subprocess.Popen(["/usr/sbin/mosquitto", "-c", self.config],
                                            stdout=log, stderr=log)

        def listening():
            assert self.process.poll() is None, open(self.log).read()
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return True
            except OSError:
                return False
        eventually(listening, 10, "mosquitto listening")

    def stop(self):
        if self.process and self.process.poll() is None:
            self.process.terminate()
            self.process.wait(10)
        self.process = None


class _BridgeNode:
    """One broker of a BridgedMosquitto, as cluster.py's Node: its port and process."""

    def __init__(self, index, broker):
        self.index = index
        self.name = f"mosquitto{index + 1}"
        self.broker = broker
        self.mqtt_port = broker.port

    @property
    def process(self):
        return self.broker.process

    def running(self):
        return self.broker.process is not None and self.broker.process.poll() is None

    def log_tail(self, lines=40):
        try:
            with open(self.broker.log, errors="replace") as f:
                return "".join(f.readlines()[-lines:])
        except OSError as e:
            return f"({e})"


class BridgedMosquitto:
    """Two Mosquitto brokers on loopback joined by a bridge, with the interface of
    tests/support/cluster.py's clusters (nodes, start, stop_node, kill_node, start_node,
    close): the bridge is a `connection` of node 1 (index 0) to node 2, carrying `topics`
    both ways. Ready (start, start_node) means a message published on either node reaches a
    subscriber on the other, through the bridge: seconds in timings. A broker or bridge that
    does not come up raises ClusterError with its log."""

    kind = "Mosquitto bridge"
    credentials = None
    PROBE = "fleet-probe"

    def __init__(self, directory, topics=("spBv1.0/#", "ioportd/#", "homeassistant/#"),
                 bridge_options="", deadline=30.0):
        from cluster import ClusterError
        self.ClusterError = ClusterError
        self.dir = os.path.abspath(directory)
        self.deadline = deadline * SLOWDOWN
        self.timings = {}
        self.nodes = []
        for index in range(2):
            node_dir = os.path.join(self.dir, f"mosquitto{index + 1}")
            os.makedirs(node_dir, exist_ok=True)
            self.nodes.append(_BridgeNode(index, Broker(node_dir)))
        with open(self.nodes[0].broker.config, "a") as f:
            f.write(f"connection fleet-bridge\naddress 127.0.0.1:{self.nodes[1].mqtt_port}\n")
            for topic in (*topics, f"{self.PROBE}/#"):
                f.write(f"topic {topic} both 1\n")
            f.write(bridge_options.rstrip("\n") + "\n" if bridge_options else "")

    def _start_broker(self, index):
        node = self.nodes[index]
        try:
            node.broker.start()
        except AssertionError as e:
            raise self.ClusterError(f"{self.kind}: {node.name} did not start: {e}\n"
                                    f"{node.log_tail()}") from None

    def start(self):
        began = time.monotonic()
        try:
            for index in (1, 0):   # the bridge's far end first
                self._start_broker(index)
            self.wait_bridged()
        except BaseException:
            self.close()
            raise
        self.timings["start"] = time.monotonic() - began
        return self

    def wait_bridged(self):
        """Until a message published on each node reaches a subscriber on the other; seconds."""
        import paho.mqtt.client as mqtt
        began = time.monotonic()
        clients, seen = [], [set(), set()]
        try:
            for index in range(2):
                client = mqtt.Client(f"probe-{index}-{time.monotonic_ns()}", clean_session=True,
                                     protocol=mqtt.MQTTv311)
                client.on_message = lambda _c, box, m: box.add(m.topic)
                client.user_data_set(seen[index])
                client.connect("127.0.0.1", self.nodes[index].mqtt_port, keepalive=30)
                client.loop_start()
                clients.append(client)
            until = time.monotonic() + self.deadline
            n = 0
            while True:
                topics = [f"{self.PROBE}/{index}/{n}" for index in range(2)]
                for index in range(2):   # subscribed again: idempotent, and sure after a CONNACK
                    clients[index].subscribe(f"{self.PROBE}/#", 1)
                    clients[index].publish(topics[index], "probe", qos=1)
                step = time.monotonic() + 0.5
                while time.monotonic() < step:
                    if topics[0] in seen[1] and topics[1] in seen[0]:
                        seconds = time.monotonic() - began
                        self.timings["bridged"] = seconds
                        return seconds
                    time.sleep(0.01)
                for node in self.nodes:
                    if not node.running():
                        raise self.ClusterError(f"{self.kind}: {node.name} exited\n"
                                                f"{node.log_tail()}")
                if time.monotonic() > until:
                    raise self.ClusterError(
                        f"{self.kind}: no message crossed the bridge within {self.deadline} s "
                        f"(node 1 to 2: {topics[0] in seen[1]}, 2 to 1: {topics[1] in seen[0]})"
                        f"\n{self.nodes[0].log_tail()}\n{self.nodes[1].log_tail()}")
                n += 1
        finally:
            for client in clients:
                client.disconnect()
                client.loop_stop()

    def stop_node(self, index):
        """SIGTERM (Mosquitto's clean stop) and the wait for its exit: seconds."""
        began = time.monotonic()
        self.nodes[index].broker.stop()
        return time.monotonic() - began

    def kill_node(self, index):
        """SIGKILL (a crash): seconds until gone."""
        broker = self.nodes[index].broker
        began = time.monotonic()
        broker.process.kill()
        broker.process.wait(10)
        broker.process = None
        return time.monotonic() - began

    def start_node(self, index):
        """Starts node `index` again, on its port, and waits until the bridge carries messages
        both ways: seconds."""
        began = time.monotonic()
        self._start_broker(index)
        self.wait_bridged()
        return time.monotonic() - began

    def close(self):
        for node in self.nodes:
            if node.running():
                node.broker.process.kill()
                node.broker.process.wait(10)
            node.broker.process = None
