"""What a process of the test's costs, and the unit's MemoryMax= around it.

    limit = MemoryLimit(256 << 20)   # a memory cgroup, as systemd makes for MemoryMax=256M
    limit.add(pid)                   # the process and what it allocates from now on
    peak_rss(pid), cpu_seconds(pid)  # VmHWM in bytes; user + system CPU in seconds
    limit.close()
    if RSS_TELLS: ...                # a bound on RSS means something for this build's processes

MemoryLimit uses cgroup v2 (memory.max) or v1 (memory.limit_in_bytes), whichever this machine
mounts writable for the test; where neither is (not root, no controller), `available` is False
and add() does nothing: the tests then still bound the peak RSS they measure, which is what the
limit would enforce by killing the process.

Under AddressSanitizer (scripts/test's second stage exports ASAN_OPTIONS to the tests and the
processes they start) the peak RSS says nothing about what a process kept: ASan's quarantine holds
up to 256 MB of freed memory resident, so a daemon that only allocates and frees as it runs grows
by a hundred megabytes in a minute. There a test checks the behaviour (refused, counted, still
answering) and leaves the bound on memory to the Release stage, where it is measured; and
MemoryLimit gives the quarantine and ASan's shadow memory 512 MiB on top of the unit's limit, or a
sanitized daemon at the limit stalls in the kernel's reclaim where a Release one would not be near
it (mqtt_json's huge /set waited a minute for a small one so in scripts/test's second stage).
"""

import os
import time

RSS_TELLS = "ASAN_OPTIONS" not in os.environ
PAGE = os.sysconf("SC_PAGE_SIZE")
TICKS = os.sysconf("SC_CLK_TCK")


def peak_rss(pid):
    """The process's peak resident set (VmHWM), in bytes."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    raise AssertionError(f"no VmHWM for {pid}")


def cpu_seconds(pid):
    """User and system CPU the process has used, in seconds."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


class MemoryLimit:
    # (the hierarchy's root, a file only it has, the file of the limit)
    HIERARCHIES = (("/sys/fs/cgroup", "cgroup.controllers", "memory.max"),
                   ("/sys/fs/cgroup/memory", "memory.limit_in_bytes", "memory.limit_in_bytes"))

    ASAN_ROOM = 512 << 20  # the quarantine (256 MB) and the shadow memory: see above

    def __init__(self, limit_bytes):
        if not RSS_TELLS:
            limit_bytes += self.ASAN_ROOM
        self.path = None
        name = f"ioportd-test-{os.getpid()}-{time.monotonic_ns()}"
        for root, marker, limit_file in self.HIERARCHIES:
            if not os.path.exists(os.path.join(root, marker)):
                continue
            path = os.path.join(root, name)
            try:
                os.mkdir(path)
                with open(os.path.join(path, limit_file), "w") as f:
                    f.write(str(limit_bytes))
            except OSError:
                if os.path.isdir(path):
                    os.rmdir(path)
                continue
            self.path = path
            break

    @property
    def available(self):
        return self.path is not None

    def add(self, pid):
        if self.path:
            with open(os.path.join(self.path, "cgroup.procs"), "w") as f:
                f.write(str(pid))

    def close(self):
        if self.path:
            try:
                os.rmdir(self.path)
            except OSError:
                pass  # a process still in it; the cgroup goes with it
