#!/usr/bin/python3
"""The status page of the real ioportd, on the real simulator, in headless Chromium (issue 16
§3): an input changed in the simulator shows on the page without a reload, a faulted module
shows as not online, the console has no errors. Saves the screenshots to OUTDIR.

Usage: live_page_test.py IOPORTD IOPORT_SIM OUTDIR
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import status_page_test  # noqa: E402  (beside this file)

IOPORTD, IOPORT_SIM, OUTDIR = sys.argv[1], sys.argv[2], sys.argv[3]
HUB = "dim16:0,dom16:0,acm3p:0,lim16:0,rgbdm:0,mux8m:0,dccim:0,dcvim:0"


def eventually(condition, deadline):
    until = time.monotonic() + deadline
    while not condition():
        if time.monotonic() >= until:
            return False
        time.sleep(0.01)
    return True


class Rig:
    """A simulated hub with every module type but acm3c, a simulated ID-2, ioportd on both."""

    def __init__(self, directory):
        self.dir = directory
        self.processes = []
        self.control = os.path.join(directory, "hub.ctl")
        self.sim("--link", os.path.join(directory, "ttyHUB"), "--control", self.control,
                 "--hub", HUB)
        self.sim("--link", os.path.join(directory, "ttyID2"), "--id2")
        config = os.path.join(directory, "ioportd.yaml")
        with open(config, "w") as f:
            f.write(f"""modbus:
  listen: "127.0.0.1:0"
http:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {directory}/ttyHUB
    unit_id: 1
    timeout: 50ms
    modules:
""" + "".join(f"      - {{ type: {m.split(':')[0]}, number: 0 }}\n" for m in HUB.split(",")) + f"""
  - name: press
    protocol: id2
    device: {directory}/ttyID2
    baud: 9600
    unit_id: 2
""")
        self.log = os.path.join(directory, "ioportd.log")
        with open(self.log, "w") as log:
            self.daemon = subprocess.Popen([IOPORTD, "--config", config], stdout=log,
                                           stderr=subprocess.STDOUT)
        self.processes.append(self.daemon)
        found = {}

        def listening():
            with open(self.log) as f:
                text = f.read()
            for name, pattern in (("http", r"HTTP on http://127\.0\.0\.1:(\d+)/"),
                                  ("modbus", r"Modbus TCP on 127\.0\.0\.1:(\d+)")):
                if m := re.search(pattern, text):
                    found[name] = int(m.group(1))
            return len(found) == 2 or self.daemon.poll() is not None
        assert eventually(listening, 10) and len(found) == 2, self.read_log()
        self.url = f"http://127.0.0.1:{found['http']}/"
        self.modbus_port = found["modbus"]

    def sim(self, *args):
        sim = subprocess.Popen([IOPORT_SIM, "--no-line-timing", *args], stdout=subprocess.PIPE,
                               text=True)
        self.processes.append(sim)
        banner = sim.stdout.readline()
        assert banner.startswith("ioport-sim: "), banner

    def ctl(self, command):
        out = subprocess.run([IOPORT_SIM, "ctl", self.control, *command.split()],
                             capture_output=True, text=True, timeout=10)
        assert out.returncode == 0, out.stderr

    def read_log(self):
        with open(self.log) as f:
            return f.read()

    def close(self):
        for process in reversed(self.processes):
            process.terminate()
        for process in self.processes:
            process.wait(5)


def main():
    directory = tempfile.mkdtemp(prefix="ioportd-page-")
    rig = None
    try:
        rig = Rig(directory)
        # Values a person would recognise on the screenshot.
        rig.ctl("set dim16:0 0x0001")
        rig.ctl("set lim16:0 0x8011")
        rig.ctl("set acm3p:0 13208 41203 4095")
        rig.ctl("set dccim:0 22539")
        rig.ctl("set dcvim:0 49610")
        subprocess.run(["mbpoll", "-1", "-m", "tcp", "-p", str(rig.modbus_port), "-a", "1",
                        "-t", "4", "-r", "1", "127.0.0.1", "0x0808"],
                       capture_output=True, timeout=10, check=True)
        status_page_test.run(
            rig.url,
            change_input=lambda: rig.ctl("set dim16:0 0x000D"),
            expected_word=0x000D,
            fault=lambda: rig.ctl("fault acm3p:0 silent"),
            fault_module="acm3p 0",
            screenshot_path=os.path.join(OUTDIR, "status-page.png"))
        print(f"live_page_test: passed; screenshots in {OUTDIR}")
        return 0
    except AssertionError as failure:
        print(f"live_page_test: FAILED: {failure}", file=sys.stderr)
        if rig:
            print("--- ioportd log ---\n" + rig.read_log(), file=sys.stderr)
        return 1
    finally:
        if rig:
            rig.close()
        shutil.rmtree(directory, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
