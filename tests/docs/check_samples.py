#!/usr/bin/env python3
"""Checks that the sample outputs shown in the Markdown files are what the programs print today
(issue 43), as check_links.py keeps the links true.

Usage: check_samples.py [ROOT [BINDIR...]]   (ROOT defaults to the current directory, BINDIR to
ROOT/build/daemon and ROOT/build/tools; ctest's doc_samples passes the source directory and the
directories of the ioportd, ioportctl and ioport-sim it built)

A sample is a fenced code block right after a marker line, an HTML comment that renders as
nothing:

    <!-- sample output -->          the block's first line is `$ COMMAND`, the rest its output
    <!-- sample output: COMMAND --> the whole block is COMMAND's output

COMMAND runs under /bin/sh in ROOT, with the BINDIRs first on PATH (so `ioportd` is the one just
built), stdout and stderr together as a terminal shows them, at most 60 s. Its output must be
the sample's lines exactly; a last line `...` says that the output goes on, and then the lines
before it must be the output's first lines. Samples of what depends on the moment (logs of a
running daemon, measurements) are not marked, and not checked.

The files are those of check_links.py (tracked and new Markdown files, or every *.md without
git). Every sample that differs is printed as FILE:LINE: COMMAND and a diff; a marker without a
fenced block after it, or a command that does not finish, counts as a difference. The exit
status is 1 if there was any, 2 if no sample was found at all, 0 otherwise. Python's standard
library only.
"""

import difflib
import os
import re
import subprocess
import sys
from pathlib import Path

from check_links import FENCE, markdown_files

MARKER = re.compile(r"^ {0,3}<!--\s*sample output(?::\s*(.*?))?\s*-->\s*$")
TIMEOUT_S = 60


def samples(path: Path):
    """(line number of the opening fence, command, expected lines) of each marked block; command
    None, with the reason as expected, when the marker is not followed by a proper block."""
    lines = path.read_text(encoding="utf-8").split("\n")
    i = 0
    while i < len(lines):
        m = MARKER.match(lines[i])
        if not m:
            i += 1
            continue
        marker_line, command = i + 1, m.group(1)
        fence = FENCE.match(lines[i + 1]) if i + 1 < len(lines) else None
        if not fence:
            yield marker_line, None, ["the marker is not followed by a fenced block"]
            i += 1
            continue
        char, length = fence.group(1)[0], len(fence.group(1))
        body, j = [], i + 2
        while j < len(lines):
            end = FENCE.match(lines[j])
            if end and end.group(1)[0] == char and len(end.group(1)) >= length \
                    and not lines[j].strip().strip(char):
                break
            body.append(lines[j])
            j += 1
        if command is None:
            if not body or not body[0].startswith("$ "):
                yield marker_line, None, ["the block does not begin with `$ COMMAND`"]
                i = j + 1
                continue
            command, body = body[0][2:], body[1:]
        yield marker_line + 1, command, body
        i = j + 1


def differences(root: Path, env: dict, command: str, expected: list[str]) -> list[str]:
    """The diff of the sample against the command's output; empty if the sample is true."""
    try:
        run = subprocess.run(["/bin/sh", "-c", command], cwd=root, env=env, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             timeout=TIMEOUT_S)
        output = run.stdout
    except subprocess.TimeoutExpired:
        return [f"did not finish within {TIMEOUT_S} s"]
    actual = output.split("\n")
    if actual and actual[-1] == "":
        actual.pop()
    shown = expected
    if expected and expected[-1].strip() == "...":
        shown = expected[:-1]
        actual = actual[:len(shown)]
    if actual == shown:
        return []
    return list(difflib.unified_diff(shown, actual, "sample", "output", lineterm=""))


def main(argv: list[str]) -> int:
    root = Path(os.path.abspath(argv[1] if len(argv) > 1 else ".")).resolve()
    bindirs = argv[2:] or [str(root / "build/daemon"), str(root / "build/tools")]
    env = dict(os.environ, PATH=os.pathsep.join(bindirs + [os.environ.get("PATH", "")]))
    checked = wrong = 0
    files = markdown_files(root)
    for path in files:
        for line, command, expected in samples(path):
            where = f"{path.relative_to(root).as_posix()}:{line}"
            checked += 1
            if command is None:
                print(f"{where}: {expected[0]}")
                wrong += 1
                continue
            diff = differences(root, env, command, expected)
            if diff:
                print(f"{where}: {command}: the sample is not what it prints")
                print("\n".join("    " + d for d in diff))
                wrong += 1
    if checked == 0:
        print(f"check_samples: no marked sample in the Markdown files under {root}",
              file=sys.stderr)
        return 2
    if wrong:
        print(f"{wrong} of {checked} samples in {len(files)} Markdown files differ")
        return 1
    print(f"{checked} samples in {len(files)} Markdown files: each is what its command prints")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
