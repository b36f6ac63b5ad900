"""A test's packages from the npm registry (Node-RED, Tahu), installed once per lock file.

    npm.install(SOURCE, DIR, ENTRY)   # npm ci of SOURCE's package.json and package-lock.json
                                      # into DIR, unless DIR holds the same lock file and ENTRY
                                      # (a path under DIR) already
"""
import filecmp
import os
import shutil
import subprocess
import sys
import time


def install(source, directory, entry):
    lock = os.path.join(source, "package-lock.json")
    installed = os.path.join(directory, "package-lock.json")
    if (os.path.exists(os.path.join(directory, entry)) and os.path.exists(installed)
            and filecmp.cmp(lock, installed, False)):
        return
    os.makedirs(directory, exist_ok=True)
    for name in ("package.json", "package-lock.json"):
        shutil.copy(os.path.join(source, name), directory)
    started = time.monotonic()
    done = subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--omit=dev", "--prefix",
                           directory], capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        sys.exit(f"npm ci of {source} into {directory} failed (exit {done.returncode}); the npm "
                 f"registry must be reachable:\n{done.stderr}")
    print(f"{os.path.basename(source)} installed into {directory} in "
          f"{time.monotonic() - started:.0f} s")
