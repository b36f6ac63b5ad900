#!/usr/bin/python3
"""Smoke test of tests/support/cluster.py on this machine: starts each two-node cluster
(RabbitMQ 3.10 with a mirrored-queue policy, ejabberd 23.01), a subscriber on node 2 and a
publisher on node 1 (QoS 1; a retained message), checks what crosses the nodes, then stops
node 1 cleanly, starts it again, kills it (SIGKILL), and checks that node 2 still serves each
time; prints the timings (start, join, failover, restart, teardown) and the nodes' memory.

    /usr/bin/python3 tests/support/cluster_smoke.py [rabbitmq|ejabberd ...]

Exits 1 when a check fails (a cluster that cannot start raises: nothing is skipped).
"""

import os
import sys
import tempfile
import threading
import time

import paho.mqtt.client as mqtt

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cluster import ClusterError, EjabberdCluster, RabbitCluster, mqtt_connack  # noqa: E402

failures = []
# exact topics, no wildcard: RabbitMQ 3.10 sends retained messages only to a subscription whose
# filter is the very topic (none to smoke/#)
TOPICS = ("smoke/retained", "smoke/live", "smoke/after")


def check(ok, what):
    print(f"  {'ok  ' if ok else 'FAIL'} {what}")
    if not ok:
        failures.append(what)


class Client:
    """A paho MQTT 3.1.1 client on one node, with what it received."""

    def __init__(self, cluster, index, client_id):
        self.client = mqtt.Client(client_id, clean_session=True, protocol=mqtt.MQTTv311)
        if cluster.credentials:
            self.client.username_pw_set(*cluster.credentials)
        self.received = []
        self.connected = threading.Event()
        self.disconnected_at = None
        self.lock = threading.Lock()
        self.client.on_message = self._message
        self.client.on_connect = lambda c, u, f, rc: rc == 0 and self.connected.set()
        self.client.on_disconnect = self._disconnect
        self.client.connect("127.0.0.1", cluster.nodes[index].mqtt_port, keepalive=30)
        self.client.loop_start()
        if not self.connected.wait(10):
            raise ClusterError(f"{client_id}: no CONNACK from node {index + 1}")

    def _message(self, client, userdata, message):
        with self.lock:
            self.received.append((message.topic, message.payload, message.retain,
                                  time.monotonic()))

    def _disconnect(self, client, userdata, rc):
        self.disconnected_at = time.monotonic()

    def subscribe(self, topics=TOPICS, qos=1):
        done = threading.Event()
        self.client.on_subscribe = lambda c, u, mid, granted: done.set()
        self.client.subscribe([(topic, qos) for topic in topics])
        if not done.wait(10):
            raise ClusterError(f"no SUBACK for {topics}")

    def publish(self, topic, payload, qos=1, retain=False):
        info = self.client.publish(topic, payload, qos, retain)
        info.wait_for_publish(10)
        return info.is_published()

    def got(self, payload, deadline=10.0):
        """The arrival time of `payload`, or None after the deadline."""
        until = time.monotonic() + deadline
        while time.monotonic() < until:
            with self.lock:
                for topic, data, retain, at in self.received:
                    if data == payload:
                        return at
            time.sleep(0.01)
        return None

    def close(self):
        self.client.disconnect()
        self.client.loop_stop()


def node2_serves(cluster, tag, since):
    """A new subscriber and a new publisher on node 2, the one receiving from the other:
    seconds from `since` to the first CONNACK on node 2 (polled with raw CONNECTs), to the
    subscriber's SUBACK, the publisher's CONNACK and the delivery."""
    until = time.monotonic() + 30
    while mqtt_connack(cluster.nodes[1].mqtt_port, cluster.credentials) != 0:
        if time.monotonic() > until:
            raise ClusterError(f"after {tag}: no CONNACK from node 2 within 30 s")
        time.sleep(0.01)
    print(f"  after the {tag}: first CONNACK from node 2 at +{time.monotonic() - since:.3f} s")
    sub = Client(cluster, 1, f"smoke-sub2-{tag}")
    sub.subscribe()
    print(f"  after the {tag}: SUBACK on node 2 at +{time.monotonic() - since:.3f} s")
    pub = Client(cluster, 1, f"smoke-pub2-{tag}")
    connected = time.monotonic() - since
    payload = f"after-{tag}".encode()
    pub.publish("smoke/after", payload)
    at = sub.got(payload)
    check(at is not None, f"after {tag}: a publisher on node 2 reaches a subscriber on node 2")
    pub.close()
    sub.close()
    return connected, (at - since) if at else None


def smoke(cluster):
    kind = cluster.kind
    print(f"== {kind}")
    began = time.monotonic()
    cluster.start()
    print(f"  started in {time.monotonic() - began:.2f} s (nodes {cluster.timings['nodes']:.2f} s, "
          f"join and status {cluster.timings['join']:.2f} s)")
    memory = cluster.memory()
    print("  RSS: " + ", ".join(f"{name} {rss / 2**20:.0f} MiB" for name, rss in memory.items()))
    mqtt5 = mqtt_connack(cluster.nodes[0].mqtt_port, cluster.credentials, level=5)
    print(f"  MQTT 5 CONNECT to node 1: "
          f"{'closed without a CONNACK' if mqtt5 is None else f'CONNACK reason code {mqtt5}'}")

    # retained through node 1, then subscribers on both nodes
    pub = Client(cluster, 0, "smoke-pub1")
    check(pub.publish("smoke/retained", b"retained-1", retain=True), "retained PUBACK on node 1")
    sub2 = Client(cluster, 1, "smoke-sub2")
    sub2.subscribe()
    sub1 = Client(cluster, 0, "smoke-sub1")
    sub1.subscribe()
    check(sub1.got(b"retained-1", 5) is not None, "retained message delivered on node 1")
    remote = sub2.got(b"retained-1", 3)
    print(f"  retained through node 1, subscriber on node 2: "
          f"{'delivered (cluster-wide)' if remote else 'not delivered (node-local)'}")

    # QoS 1 across the nodes
    sent = time.monotonic()
    check(pub.publish("smoke/live", b"live-1"), "QoS 1 PUBACK on node 1")
    at = sub2.got(b"live-1")
    check(at is not None, "QoS 1 from node 1 delivered on node 2")
    if at:
        print(f"  node 1 -> node 2 latency {1000 * (at - sent):.1f} ms")
    sub1.close()

    # clean stop of node 1
    stopped_at = time.monotonic()
    seconds = cluster.stop_node(0)
    print(f"  node 1 stopped cleanly in {seconds:.2f} s; the publisher on it noticed after "
          f"{(pub.disconnected_at or float('nan')) - stopped_at:.2f} s")
    connected, delivered = node2_serves(cluster, "stop", stopped_at)
    pub.client.loop_stop()      # not before: it waits up to a second for paho's select
    print(f"  after the stop: node 2 CONNACK at +{connected:.2f} s, delivery at "
          f"+{delivered or float('nan'):.2f} s from the stop command")
    check(cluster.running_nodes(1) == {cluster.nodes[1].name}, "node 2 sees itself alone")
    sub2_alive = sub2.connected.is_set() and sub2.disconnected_at is None
    check(sub2_alive, "the subscriber on node 2 stayed connected through the stop")

    seconds = cluster.start_node(0)
    print(f"  node 1 started again, back in the cluster, in {seconds:.2f} s")

    # kill -9 of node 1
    pub = Client(cluster, 0, "smoke-pub1b")
    killed_at = time.monotonic()
    seconds = cluster.kill_node(0)
    print(f"  node 1 killed (SIGKILL) in {seconds:.3f} s")
    connected, delivered = node2_serves(cluster, "kill", killed_at)
    print(f"  after the kill: node 2 CONNACK at +{connected:.2f} s, delivery at "
          f"+{delivered or float('nan'):.2f} s from the kill; the publisher on node 1 noticed "
          f"after {(pub.disconnected_at or float('nan')) - killed_at:.3f} s")
    pub.client.loop_stop()
    cluster.wait_cluster([cluster.nodes[1].name], [1], 120)
    print(f"  node 2's status without node 1 at +{time.monotonic() - killed_at:.2f} s")
    check(sub2.disconnected_at is None,
          "the subscriber on node 2 stayed connected through the kill")

    seconds = cluster.start_node(0)
    print(f"  node 1 started again after the kill in {seconds:.2f} s")
    sub2.close()

    cluster.close()
    print(f"  teardown in {cluster.timings['close']:.2f} s")


def main():
    kinds = sys.argv[1:] or ["ejabberd", "rabbitmq"]
    with tempfile.TemporaryDirectory(prefix="cluster-smoke-") as directory:
        for kind in kinds:
            if kind == "rabbitmq":
                cluster = RabbitCluster(os.path.join(directory, kind), queue_policy="mirrored")
            elif kind == "ejabberd":
                cluster = EjabberdCluster(os.path.join(directory, kind))
            else:
                sys.exit(f"cluster_smoke: unknown kind {kind}")
            try:
                smoke(cluster)
            finally:
                cluster.close()
    print(f"cluster_smoke: {len(failures)} failed" + (": " + "; ".join(failures)
                                                       if failures else ""))
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
