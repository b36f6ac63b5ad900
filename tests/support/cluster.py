"""Real two-node MQTT broker clusters for the system tests: RabbitMQ 3.10 (rabbitmq_mqtt) and
ejabberd 23.01 (mod_mqtt) from Debian 12, started on loopback in a directory of the test's,
without touching the system's services: their own node names, Erlang cookie, epmd (on a port of
their own), data, log and configuration files, and ports.

    with RabbitCluster(directory) as cluster:          # or EjabberdCluster(directory)
        cluster.nodes[1].mqtt_port                     # MQTT 3.1.1 on 127.0.0.1
        cluster.credentials                            # (username, password) or None
        cluster.stop_node(0)                           # clean stop: seconds until it is gone
        cluster.kill_node(0)                           # SIGKILL of its Erlang VM
        cluster.start_node(0)                          # again, back in the cluster
        cluster.running_nodes(1)                       # as node 1 sees the cluster
        cluster.timings                                # seconds: "start", "join", ...
    # leaving the block (or close()) kills whatever the cluster started: seconds in
    # cluster.timings["close"]

Every wait has a deadline and fails with ClusterError naming what did not come up, with the
node's log tail; nothing is skipped: a cluster that cannot start on this machine raises.
Ready means, for each node: its MQTT port answers a CONNECT with a CONNACK that accepts it,
and the cluster's own status lists all the nodes as running, seen from every node.

RabbitCluster(directory, queue_policy="mirrored"): a classic mirrored-queue policy (ha-mode
all, ha-sync-mode automatic) on the MQTT plugin's subscription queues (mqtt-subscription-<client
id>qos<n>): the queue of a persistent session (Clean Session 0) lives on the node it was made
on, and without a mirror it is unavailable while that node is down; "quorum":
mqtt.durable_queue_type = quorum, a quorum queue on both nodes, which with two nodes has no
majority while one is down. extra_config: more lines of rabbitmq.conf (e.g.
"mqtt.sparkplug = true") or, for ejabberd, YAML appended to ejabberd.yml's top level (keys it
does not have yet); EjabberdCluster(listener_options={"max_payload_size": 1048576}): more
options of the mod_mqtt listener.

RabbitMQ 3.10's MQTT plugin speaks MQTT 3.1 and 3.1.1 only: an MQTT 5 CONNECT is answered by
closing the connection, without a CONNACK. ejabberd's mod_mqtt speaks 3.1.1 and 5; with the
anonymous authentication configured here it wants a user name and a password that is not empty
(any): use cluster.credentials. Retained messages are node-local in both: a subscriber on node
2 does not get what was retained through node 1. RabbitMQ 3.10 sends a retained message only to
a subscription whose filter is its very topic, never through a wildcard (a/# gets none).

RabbitMQ 3.10 with two nodes: while one is down, the MQTT plugin's client-id tracker (a Raft
cluster of the nodes) has no majority; the node starting again then waits 100 s for it, unless
nudged (RabbitCluster(nudge_restart=True), the default: see _restarted). Starting a fresh
cluster or MQTT on the node left is not affected.

The processes are started in their own sessions with PR_SET_PDEATHSIG (start the cluster from
the main thread): they die with the test process, even when it is killed.
"""

import ctypes
import json
import os
import random
import shutil
import signal
import socket
import struct
import subprocess
import time

SLOWDOWN = int(os.environ.get("IOPORT_TEST_SLOWDOWN", "1"))
ERL = "/usr/bin/erl"
EPMD = "/usr/bin/epmd"
RABBITMQ_SBIN = "/usr/lib/rabbitmq/bin"
EJABBERD_LIBS = "/usr/lib/x86_64-linux-gnu"   # holds ejabberd-23.01/ and its dependencies
EJABBERD_COOKIE_BYTES = 20


class ClusterError(RuntimeError):
    """A cluster, one of its nodes, or a command on it did not come up or did not work."""


_ports_given = set()


def free_port():
    """A port free on 127.0.0.1 now, below the kernel's ephemeral range: a port from that range
    (what bind to port 0 gives) can be taken by any outgoing connection before the broker
    binds it, e.g. a starting node's own to epmd (RabbitMQ then fails with
    dist_port_already_used). Never the same twice in a process."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            ephemeral = int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        ephemeral = 32768
    low = 20000 if ephemeral > 21000 else 1024
    for _ in range(1000):
        port = random.randrange(low, ephemeral)
        if port in _ports_given:
            continue
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        _ports_given.add(port)
        return port
    raise ClusterError(f"no free port in {low}..{ephemeral - 1} on 127.0.0.1")


def _die_with_parent():
    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def _tail(path, lines=40):
    try:
        with open(path, errors="replace") as f:
            return "".join(f.readlines()[-lines:])
    except OSError as e:
        return f"({e})"


def _session_pids(sid):
    """The processes of session `sid` (what a node started with setsid left behind)."""
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if fields[0] != "Z" and int(fields[3]) == sid:   # state, ppid, pgrp, session
            pids.append(int(entry))
    return pids


def _kill_session(sid, deadline):
    """SIGKILL every process of session `sid`, and wait until none is left. `deadline` is a
    hang's: a killed Erlang VM of a few hundred MB took more than 10 s to be gone beside two busy
    loops."""
    until = time.monotonic() + deadline
    while True:
        pids = _session_pids(sid)
        if not pids:
            return
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if time.monotonic() > until:
            raise ClusterError(f"processes {pids} of session {sid} survive SIGKILL")
        time.sleep(0.02)


def mqtt_connack(port, credentials=None, timeout=2.0, level=4, client_id="cluster-probe"):
    """CONNECT (MQTT 3.1.1 at level 4, 5 at level 5) to 127.0.0.1:port: the CONNACK's return
    or reason code (0: accepted), or None when refused or closed before a CONNACK. The
    connection is closed with a DISCONNECT after a CONNACK."""
    flags = 0x02                                       # clean session
    payload = struct.pack(">H", len(client_id)) + client_id.encode()
    if credentials:
        user, password = (x.encode() for x in credentials)
        flags |= 0xC0
        payload += struct.pack(">H", len(user)) + user + struct.pack(">H", len(password)) \
            + password
    header = struct.pack(">H", 4) + b"MQTT" + bytes([level, flags]) + struct.pack(">H", 30)
    if level == 5:
        header += b"\x00"                              # no properties
    body = header + payload
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
            s.sendall(bytes([0x10, len(body)]) + body)
            answer = b""
            while len(answer) < 4:
                chunk = s.recv(4 - len(answer))
                if not chunk:
                    return None
                answer += chunk
            if answer[0] != 0x20:
                return None
            code = answer[3]       # after the flags: 3.1.1's return code, 5's reason code
            try:
                s.sendall(b"\xe0\x00")
            except OSError:
                pass
            return code
    except OSError:
        return None


class Node:
    """One broker node: its Erlang node name, ports and files, and its VM's process."""

    def __init__(self, index, name, directory):
        self.index = index
        self.name = name                       # e.g. rabbit1@localhost
        self.dir = directory
        self.mqtt_port = free_port()
        self.process = None
        self.stdout = os.path.join(directory, "stdout.log")
        self.logs = [self.stdout]              # the files whose tails explain a failure

    @property
    def pid(self):
        return self.process.pid if self.process else None

    def running(self):
        return self.process is not None and self.process.poll() is None

    def log_tail(self, lines=40):
        return "\n".join(f"--- {path} (last {lines} lines):\n{_tail(path, lines)}"
                         for path in self.logs)


class _ErlangCluster:
    """What both kinds share: the private epmd and cookie, starting, waiting, stopping."""

    kind = "broker"
    node_prefix = "node"
    credentials = None

    def __init__(self, directory, size=2, deadline=120.0, extra_config=""):
        self.dir = os.path.abspath(directory)
        self.size = size
        self.deadline = deadline * SLOWDOWN
        self.extra_config = extra_config
        self.home = os.path.join(self.dir, "home")
        os.makedirs(self.home, exist_ok=True)
        cookie = os.path.join(self.home, ".erlang.cookie")
        if not os.path.exists(cookie):
            with open(os.open(cookie, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o400), "w") as f:
                f.write(os.urandom(EJABBERD_COOKIE_BYTES).hex().upper())
        self.epmd_port = free_port()
        self.epmd = None
        self.nodes = []
        for i in range(size):
            node_dir = os.path.join(self.dir, f"{self.node_prefix}{i + 1}")
            os.makedirs(node_dir, exist_ok=True)
            self.nodes.append(self._make_node(i, f"{self.node_prefix}{i + 1}@localhost",
                                              node_dir))
        self.timings = {}
        self._ctl_count = 0

    # --- to be provided by each kind
    def _make_node(self, index, name, directory):
        raise NotImplementedError

    def _node_command(self, node):
        """(argv, environment additions) that run the node's VM in the foreground."""
        raise NotImplementedError

    def _ctl(self, node, *args, timeout=30.0):
        """The kind's control command on `node`: CompletedProcess."""
        raise NotImplementedError

    def running_nodes(self, viewpoint):
        """The node names that node `viewpoint` sees running in its cluster."""
        raise NotImplementedError

    def _join(self, node, seed):
        raise NotImplementedError

    def _stop_command(self, node):
        raise NotImplementedError

    # --- common
    def env(self, **more):
        """The environment of every Erlang program of this cluster: its own HOME (cookie),
        its own epmd, distribution on loopback only."""
        env = {k: v for k, v in os.environ.items() if not k.startswith(("ERL_", "RABBITMQ_"))}
        env.update(HOME=self.home, ERL_EPMD_PORT=str(self.epmd_port),
                   ERL_EPMD_ADDRESS="127.0.0.1", LANG="C.UTF-8", LC_ALL="C.UTF-8")
        env.update(more)
        return env

    def _popen(self, argv, env, log_path, cwd=None):
        log = open(log_path, "ab")
        try:
            return subprocess.Popen(argv, env=env, cwd=cwd or self.dir, stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=subprocess.STDOUT,
                                    start_new_session=True, preexec_fn=_die_with_parent)
        finally:
            log.close()

    def _run(self, argv, env, timeout, what):
        """A control command to its end: CompletedProcess; past `timeout`, the command and
        all it started (rabbitmqctl is a script over an escript's VM) are killed."""
        proc = subprocess.Popen(argv, env=env, cwd=self.dir, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True, preexec_fn=_die_with_parent)
        try:
            out, err = proc.communicate(timeout=timeout * SLOWDOWN)
        except subprocess.TimeoutExpired:
            _kill_session(proc.pid, 60 * SLOWDOWN)
            out, err = proc.communicate()
            raise ClusterError(f"{self.kind}: {what} took more than {timeout * SLOWDOWN} s: "
                               f"{out}{err}") from None
        _kill_session(proc.pid, 60 * SLOWDOWN)
        return subprocess.CompletedProcess(argv, proc.returncode, out, err)

    def _ctl_ok(self, node, *args, timeout=30.0):
        out = self._ctl(node, *args, timeout=timeout)
        if out.returncode != 0:
            raise ClusterError(f"{self.kind}: {' '.join(args)} on {node.name} exited "
                               f"{out.returncode}:\n{out.stdout}{out.stderr}\n"
                               f"{node.log_tail()}")
        return out.stdout

    def _start_epmd(self):
        if self.epmd and self.epmd.poll() is None:
            return
        log = os.path.join(self.dir, "epmd.log")
        self.epmd = self._popen([EPMD, "-port", str(self.epmd_port), "-address", "127.0.0.1"],
                                self.env(), log)
        self._wait(lambda: self._epmd_up(log), f"epmd on 127.0.0.1:{self.epmd_port}",
                   lambda: _tail(log), 10)

    def _epmd_up(self, log):
        if self.epmd.poll() is not None:
            raise ClusterError(f"epmd on port {self.epmd_port} exited {self.epmd.returncode}: "
                               f"{_tail(log)}")
        try:
            socket.create_connection(("127.0.0.1", self.epmd_port), timeout=1).close()
            return True
        except OSError:
            return False

    def _wait(self, condition, what, explain, deadline=None):
        """condition()'s first true result, polled until the deadline; ClusterError naming
        `what`, with explain()'s text, after it."""
        deadline = self.deadline if deadline is None else deadline * SLOWDOWN
        until = time.monotonic() + deadline
        while True:
            result = condition()
            if result:
                return result
            if time.monotonic() >= until:
                raise ClusterError(f"{self.kind}: not within {deadline:.0f} s: {what}\n"
                                   f"{explain()}")
            time.sleep(0.1)

    def _launch(self, node):
        argv, env = self._node_command(node)
        node.process = self._popen(argv, env, node.stdout, cwd=node.dir)

    def _mqtt_ready(self, node):
        if not node.running():
            raise ClusterError(f"{self.kind}: {node.name} exited {node.process.returncode} "
                               f"while starting\n{node.log_tail()}")
        return mqtt_connack(node.mqtt_port, self.credentials) == 0

    def wait_mqtt(self, index, deadline=None):
        """Until node `index` answers an MQTT 3.1.1 CONNECT with a CONNACK accepting it."""
        node = self.nodes[index]
        self._wait(lambda: self._mqtt_ready(node),
                   f"{node.name}'s MQTT on 127.0.0.1:{node.mqtt_port} accepting a CONNECT",
                   node.log_tail, deadline)

    def wait_cluster(self, names=None, viewpoints=None, deadline=None):
        """Until every node of `viewpoints` (the running ones) sees exactly `names` running
        (all the nodes that run)."""
        running = [n for n in self.nodes if n.running()]
        names = set(names or (n.name for n in running))
        viewpoints = viewpoints if viewpoints is not None else [n.index for n in running]
        seen = {}

        def agreed():
            for i in viewpoints:
                if not self.nodes[i].running():
                    raise ClusterError(f"{self.kind}: {self.nodes[i].name} exited "
                                       f"{self.nodes[i].process.returncode}\n"
                                       f"{self.nodes[i].log_tail()}")
                try:
                    seen[i] = self.running_nodes(i)
                except ClusterError as e:
                    seen[i] = str(e)
                if seen[i] != names:
                    return False
            return True
        self._wait(agreed, f"the cluster status showing {sorted(names)} running",
                   lambda: "seen: " + "; ".join(f"{self.nodes[i].name}: {s}"
                                                for i, s in seen.items()) + "\n"
                   + "\n".join(self.nodes[i].log_tail(20) for i in viewpoints), deadline)

    def start(self):
        """Starts every node (at once), joins the others to node 0, waits until all serve
        MQTT and the cluster lists them all. Seconds in timings: "start" in all, "nodes" to
        the nodes' MQTT, "join" the joins and the wait for the cluster status."""
        began = time.monotonic()
        try:
            self._start_epmd()
            for node in self.nodes:
                self._launch(node)
            for node in self.nodes:
                self.wait_mqtt(node.index)
            self.timings["nodes"] = time.monotonic() - began
            joined = time.monotonic()
            for node in self.nodes[1:]:
                self._join(node, self.nodes[0])
            self.wait_cluster()
            for node in self.nodes:
                self.wait_mqtt(node.index)
            self.timings["join"] = time.monotonic() - joined
        except BaseException:
            self.close()
            raise
        self.timings["start"] = time.monotonic() - began
        return self

    def start_node(self, index):
        """Starts node `index` again (after stop_node or kill_node) and waits until it serves
        MQTT and is back in the cluster; seconds."""
        node = self.nodes[index]
        if node.running():
            raise ClusterError(f"{node.name} is running")
        began = time.monotonic()
        self._start_epmd()
        self._launch(node)
        self._restarted(node)
        self.wait_mqtt(index)
        self.wait_cluster()
        return time.monotonic() - began

    def _restarted(self, node):
        """What a kind does while a node that was in the cluster starts again."""

    def stop_node(self, index, deadline=60.0):
        """Stops node `index` cleanly (its kind's stop command) and waits until its VM has
        exited; seconds from the command to the exit."""
        node = self.nodes[index]
        began = time.monotonic()
        out = self._stop_command(node)
        try:
            node.process.wait(deadline * SLOWDOWN)
        except subprocess.TimeoutExpired:
            raise ClusterError(f"{self.kind}: {node.name} still runs {deadline} s after "
                               f"its stop command ({out.returncode}: {out.stdout}"
                               f"{out.stderr})\n{node.log_tail()}") from None
        _kill_session(node.pid, 60 * SLOWDOWN)             # epmd-starter or inet_gethost leftovers
        return time.monotonic() - began

    def kill_node(self, index):
        """SIGKILL to node `index`'s VM (a crash: no clean shutdown); seconds until gone."""
        node = self.nodes[index]
        began = time.monotonic()
        node.process.send_signal(signal.SIGKILL)
        node.process.wait(10)
        _kill_session(node.pid, 60 * SLOWDOWN)
        return time.monotonic() - began

    def memory(self):
        """Resident set size in bytes per node name (its VM), of the running nodes."""
        out = {}
        for node in self.nodes:
            if node.running():
                with open(f"/proc/{node.pid}/status") as f:
                    for line in f:
                        if line.startswith("VmRSS:"):
                            out[node.name] = int(line.split()[1]) * 1024
        return out

    def close(self):
        """Kills every process this cluster started (its nodes, what they started, its
        epmd) and waits until they are gone; seconds in timings["close"]."""
        began = time.monotonic()
        errors = []
        for proc in [n.process for n in self.nodes] + [self.epmd]:
            if proc is None:
                continue
            try:
                if proc.poll() is None:
                    proc.kill()
                proc.wait(10)
                _kill_session(proc.pid, 60 * SLOWDOWN)
            except (ClusterError, subprocess.TimeoutExpired) as e:
                errors.append(str(e))
        for node in self.nodes:
            node.process = None
        self.epmd = None
        self.timings["close"] = time.monotonic() - began
        if errors:
            raise ClusterError(f"{self.kind}: teardown: {'; '.join(errors)}")

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.close()


class RabbitCluster(_ErlangCluster):
    """RabbitMQ 3.10 nodes rabbit1@localhost, rabbit2@localhost... with rabbitmq_mqtt; node i
    has its AMQP port (node.amqp_port), MQTT port and distribution port (a new one at each
    start). queue_policy: None, "mirrored" or "quorum" (see the module's doc)."""

    kind = "RabbitMQ"
    node_prefix = "rabbit"

    def __init__(self, directory, size=2, deadline=120.0, extra_config="", queue_policy=None,
                 nudge_restart=True):
        if queue_policy not in (None, "mirrored", "quorum"):
            raise ValueError(f"queue_policy {queue_policy!r}")
        self.queue_policy = queue_policy
        self.nudge_restart = nudge_restart
        for program in ("rabbitmq-server", "rabbitmqctl"):
            if not os.access(os.path.join(RABBITMQ_SBIN, program), os.X_OK):
                raise ClusterError(f"RabbitMQ: no {RABBITMQ_SBIN}/{program}: "
                                   "scripts/install-deps installs rabbitmq-server")
        super().__init__(directory, size, deadline, extra_config)

    def _make_node(self, index, name, directory):
        node = Node(index, name, directory)
        node.amqp_port = free_port()
        node.config = os.path.join(directory, "rabbitmq.conf")
        node.plugins = os.path.join(directory, "enabled_plugins")
        node.log_dir = os.path.join(directory, "log")
        node.mnesia_base = os.path.join(directory, "mnesia")
        node.logs.append(os.path.join(node.log_dir, f"{name}.log"))
        with open(node.config, "w") as f:
            f.write(f"listeners.tcp.default = 127.0.0.1:{node.amqp_port}\n"
                    f"mqtt.listeners.tcp.default = 127.0.0.1:{node.mqtt_port}\n"
                    "mqtt.allow_anonymous = true\n"
                    "loopback_users = none\n"
                    "log.file.level = info\n"
                    "log.console = false\n")
            if self.queue_policy == "quorum":
                f.write("mqtt.durable_queue_type = quorum\n")
            if self.extra_config:
                f.write(self.extra_config.rstrip("\n") + "\n")
        with open(node.plugins, "w") as f:
            f.write("[rabbitmq_mqtt].\n")
        return node

    def _node_env(self, node, **more):
        return self.env(RABBITMQ_CONF_ENV_FILE="/dev/null",     # not /etc/rabbitmq's
                        RABBITMQ_NODENAME=node.name,
                        RABBITMQ_NODE_IP_ADDRESS="127.0.0.1",
                        RABBITMQ_NODE_PORT=str(node.amqp_port),
                        RABBITMQ_MNESIA_BASE=node.mnesia_base,
                        RABBITMQ_LOG_BASE=node.log_dir,
                        RABBITMQ_CONFIG_FILE=node.config,
                        RABBITMQ_ADVANCED_CONFIG_FILE=os.path.join(node.dir, "advanced.config"),
                        RABBITMQ_ENABLED_PLUGINS_FILE=node.plugins,
                        **more)

    def _node_command(self, node):
        # RABBITMQ_ALLOW_INPUT: the script execs the VM (no shell in between, so that its PID
        # is the VM's and SIGKILL is a crash), -noinput since no one types into it.
        env = self._node_env(
            node, RABBITMQ_DIST_PORT=str(free_port()), RABBITMQ_ALLOW_INPUT="1",
            ERL_CRASH_DUMP=os.path.join(node.dir, "erl_crash.dump"),
            RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS="-noinput "
                                                "-kernel inet_dist_use_interface {127,0,0,1}")
        return [os.path.join(RABBITMQ_SBIN, "rabbitmq-server")], env

    def _ctl(self, node, *args, timeout=30.0):
        return self._run([os.path.join(RABBITMQ_SBIN, "rabbitmqctl"), "-n", node.name,
                          *args], self._node_env(node), timeout,
                         f"rabbitmqctl {' '.join(args)} on {node.name}")

    def running_nodes(self, viewpoint):
        node = self.nodes[viewpoint]
        out = self._ctl(node, "cluster_status", "--formatter", "json")
        if out.returncode != 0:
            raise ClusterError(f"cluster_status exited {out.returncode}: "
                               f"{(out.stdout + out.stderr).strip()[-300:]}")
        try:
            return set(json.loads(out.stdout)["running_nodes"])
        except (ValueError, KeyError) as e:
            raise ClusterError(f"cluster_status: {e}: {out.stdout[-300:]}") from None

    def _join(self, node, seed):
        self._ctl_ok(node, "stop_app")
        self._ctl_ok(node, "join_cluster", seed.name)
        self._ctl_ok(node, "start_app", timeout=self.deadline)

    def start(self):
        super().start()
        if self.queue_policy == "mirrored":
            self.set_policy()
        return self

    def set_policy(self):
        """The classic mirrored-queue policy on the MQTT plugin's subscription queues
        (mqtt-subscription-<client id>qos<n>): each on every node, synchronised at once."""
        self._ctl_ok(self.nodes[0], "set_policy", "--apply-to", "queues", "mqtt-ha",
                     "^mqtt-subscription-",
                     '{"ha-mode":"all","ha-sync-mode":"automatic"}')

    def clear_policy(self):
        """No mirrored-queue policy (again): a queue lives on the node it was declared on."""
        self._ctl_ok(self.nodes[0], "clear_policy", "mqtt-ha")

    def _stop_command(self, node):
        return self._ctl(node, "stop", timeout=60)

    def _restarted(self, node):
        """The MQTT plugin tracks client ids in a Raft cluster (Ra's mqtt_node) of all the
        nodes. With two, the one left has no majority, so no leader; a node starting again
        first asks it for the members (ra:members, 100 s timeout) and only then restarts its
        own Ra member: it boots in ~107 s instead of ~7. nudge_restart (the default) restarts
        that member from outside as soon as Ra runs in the booting node, which gives the
        majority back at once. Off: RabbitMQ 3.10's own behaviour, measured."""
        if not self.nudge_restart:
            return
        seen = []

        def nudged():
            if not node.running():
                raise ClusterError(f"RabbitMQ: {node.name} exited {node.process.returncode} "
                                   f"while starting again\n{node.log_tail()}")
            out = self._ctl(node, "eval",
                            "ra:restart_server(coordination, {mqtt_node, node()}).")
            seen[:] = [(out.stdout + out.stderr).strip()[-200:]]
            return out.returncode == 0 and (out.stdout.strip() == "ok"
                                            or "already_started" in out.stdout)
        self._wait(nudged, f"Ra's mqtt_node restarted on {node.name}",
                   lambda: f"last answer: {seen}\n{node.log_tail()}")


class EjabberdCluster(_ErlangCluster):
    """ejabberd 23.01 nodes ejabberd1@localhost, ejabberd2@localhost... with mod_mqtt on a
    port each, virtual host "localhost", anonymous login: MQTT clients give a user name and a
    password, any but not empty (credentials). Its VM is run by erl directly, not through
    ejabberdctl, which as root becomes the system's user ejabberd (with that user's cookie)."""

    kind = "ejabberd"
    node_prefix = "ejabberd"
    credentials = ("ioportd", "anonymous")

    def __init__(self, directory, size=2, deadline=120.0, extra_config="",
                 listener_options=None):
        self.listener_options = listener_options or {}
        if not os.path.isdir(os.path.join(EJABBERD_LIBS, "ejabberd-23.01")) \
                or not os.access(ERL, os.X_OK):
            raise ClusterError(f"ejabberd: no {EJABBERD_LIBS}/ejabberd-23.01 or {ERL}: "
                               "scripts/install-deps installs ejabberd")
        super().__init__(directory, size, deadline, extra_config)

    def _make_node(self, index, name, directory):
        node = Node(index, name, directory)
        node.config = os.path.join(directory, "ejabberd.yml")
        node.spool = os.path.join(directory, "spool")
        node.log_dir = os.path.join(directory, "log")
        os.makedirs(node.spool, exist_ok=True)
        os.makedirs(node.log_dir, exist_ok=True)
        node.log = os.path.join(node.log_dir, "ejabberd.log")
        node.logs += [node.log, os.path.join(node.log_dir, "error.log")]
        options = "".join(f"    {key}: {json.dumps(value)}\n"      # JSON is YAML
                          for key, value in self.listener_options.items())
        with open(node.config, "w") as f:
            f.write(f"""\
hosts:
  - localhost
loglevel: info
log_rotate_count: 0
auth_method: [anonymous]
anonymous_protocol: login_anon
allow_multiple_connections: true
listen:
  -
    port: {node.mqtt_port}
    ip: "127.0.0.1"
    module: mod_mqtt
    backlog: 1000
{options}api_permissions:
  "console commands":
    from:
      - ejabberd_ctl
    who: all
    what: "*"
modules:
  mod_mqtt: {{}}
""")
            if self.extra_config:
                f.write(self.extra_config.rstrip("\n") + "\n")
        return node

    def _node_command(self, node):
        env = self.env(EJABBERD_CONFIG_PATH=node.config, EJABBERD_LOG_PATH=node.log,
                       ERL_LIBS=EJABBERD_LIBS,
                       ERL_CRASH_DUMP=os.path.join(node.log_dir, "erl_crash.dump"),
                       ERL_CRASH_DUMP_BYTES="0")
        # what ejabberdctl's "foreground" runs, less its su, its /etc files and its epmd check
        return [ERL, "-sname", node.name, "+K", "true", "+P", "250000", "-noinput",
                "-mnesia", "dir", f'"{node.spool}"',
                "-kernel", "inet_dist_use_interface", "{127,0,0,1}",
                "-s", "ejabberd"], env

    def _ctl(self, node, *args, timeout=30.0):
        self._ctl_count += 1
        ctl_name = f"ctl{os.getpid()}-{self._ctl_count}@localhost"
        return self._run([ERL, "-sname", ctl_name, "-hidden", "-noinput",
                          "-kernel", "inet_dist_use_interface", "{127,0,0,1}",
                          "-s", "ejabberd_ctl", "-extra", node.name, *args],
                         self.env(ERL_LIBS=EJABBERD_LIBS), timeout,
                         f"ejabberdctl {' '.join(args)} on {node.name}")

    def running_nodes(self, viewpoint):
        # list_cluster: mnesia's running db nodes, one a line
        out = self._ctl(self.nodes[viewpoint], "list_cluster")
        if out.returncode != 0:
            raise ClusterError(f"list_cluster exited {out.returncode}: "
                               f"{(out.stdout + out.stderr).strip()[-300:]}")
        return set(out.stdout.split())

    def _join(self, node, seed):
        self._ctl_ok(node, "join_cluster", seed.name, timeout=self.deadline)

    def _stop_command(self, node):
        return self._ctl(node, "stop", timeout=60)


def cleanup_directory(directory):
    """Removes a cluster's directory after close() (the cookie is read-only)."""
    shutil.rmtree(directory, ignore_errors=True)
