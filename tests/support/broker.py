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

from rig import eventually, free_port


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
