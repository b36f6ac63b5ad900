#!/usr/bin/python3
"""The status page of the real ioportd, on the real simulator, in headless Chromium (issue 16
§3): an input changed in the simulator shows on the page without a reload, a faulted module
shows as not online, the console has no errors. Saves the screenshots to OUTDIR.

Usage: live_page_test.py IOPORTD IOPORT_SIM OUTDIR
"""
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "support"))
import status_page_test  # noqa: E402  (beside this file)
from rig import Rig  # noqa: E402

IOPORTD, IOPORT_SIM, OUTDIR = sys.argv[1], sys.argv[2], sys.argv[3]
HUB = "dim16:0,dom16:0,acm3p:0,lim16:0,rgbdm:0,mux8m:0,dccim:0,dcvim:0"


def config(rig):
    """ioportd on a simulated hub with every module type but acm3c and a simulated ID-2."""
    return f"""modbus:
  listen: "127.0.0.1:0"
http:
  listen: "127.0.0.1:0"
links:
  - name: hub0
    protocol: ioport
    device: {rig.hub_link}
    unit_id: 1
    timeout: 50ms
    modules:
""" + "".join(f"      - {{ type: {m.split(':')[0]}, number: 0 }}\n" for m in HUB.split(",")) + f"""
  - name: press
    protocol: id2
    device: {rig.id2_link}
    baud: 9600
    unit_id: 2
"""


def main():
    directory = tempfile.mkdtemp(prefix="ioportd-page-")
    rig = Rig(directory, IOPORTD, IOPORT_SIM)
    try:
        rig.start_hub(HUB)
        rig.start_id2()
        rig.write_config(config(rig))
        rig.start_daemon()
        url = f"http://127.0.0.1:{rig.listening_port('HTTP')}/"
        modbus_port = rig.listening_port("Modbus TCP")
        # Values a person would recognise on the screenshot.
        rig.ctl("set dim16:0 0x0001")
        rig.ctl("set lim16:0 0x8011")
        rig.ctl("set acm3p:0 13208 41203 4095")
        rig.ctl("set dccim:0 22539")
        rig.ctl("set dcvim:0 49610")
        subprocess.run(["mbpoll", "-1", "-m", "tcp", "-p", str(modbus_port), "-a", "1",
                        "-t", "4", "-r", "1", "127.0.0.1", "0x0808"],
                       capture_output=True, timeout=10, check=True)
        status_page_test.run(
            url,
            change_input=lambda: rig.ctl("set dim16:0 0x000D"),
            expected_word=0x000D,
            fault=lambda: rig.ctl("fault acm3p:0 silent"),
            fault_module="acm3p 0",
            screenshot_path=os.path.join(OUTDIR, "status-page.png"))
        print(f"live_page_test: passed; screenshots in {OUTDIR}")
        return 0
    except AssertionError as failure:
        print(f"live_page_test: FAILED: {failure}", file=sys.stderr)
        if rig.daemon:
            print("--- ioportd log ---\n" + rig.log_text(), file=sys.stderr)
        return 1
    finally:
        rig.close()
        shutil.rmtree(directory, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
