#!/usr/bin/env python3
"""Checks the relative links of every Markdown file of the repository (issue 25).

Usage: check_links.py [ROOT]   (ROOT defaults to the current directory; ctest's doc_links
passes the source directory)

The files are those git knows (`git ls-files --cached --others --exclude-standard '*.md'`:
tracked, and new ones not yet added), or, without git, every *.md under ROOT outside build
directories. In each, every relative link `[text](path)`, `[text](path#anchor)`,
`[text](#anchor)`, image `![alt](path)` and reference definition `[id]: path` must name a file
or directory that exists, and an anchor must name a heading of the Markdown file it points at,
by GitHub's rules: the heading's text without its markup (backticks, emphasis markers, link
targets, HTML tags), lower-cased, every character that is not a letter, digit, underscore,
hyphen or space removed, spaces turned into hyphens; the second heading with the same anchor
gets -1, the third -2. Explicit HTML anchors (`<a name="x">`, `id="x"`) count too.

Not checked: links with a scheme (https:, http:, mailto:, ...), links inside fenced code blocks
and code spans, and paths that lead out of the repository (../shared: the project's shared
specification lives beside it, not in it). Anchors into files that are not Markdown are not
checked (GitHub's #L10 line anchors).

Every broken link is printed as FILE:LINE: TARGET (WHY); the exit status is 1 if there was any,
0 otherwise. Python's standard library only.
"""

import os
import re
import subprocess
import sys
import urllib.parse
from pathlib import Path

FENCE = re.compile(r"^ {0,3}(?:[>\-*+] +|\d+[.)] +)*\s*(`{3,}|~{3,})")
ATX = re.compile(r"^ {0,3}(#{1,6})(?:[ \t]+(.*?))?(?:[ \t]+#+)?[ \t]*$")
SETEXT = re.compile(r"^ {0,3}(=+|-+)[ \t]*$")
HTML_ANCHOR = re.compile(r"<a\s[^>]*?\b(?:name|id)\s*=\s*[\"']([^\"']+)[\"']", re.IGNORECASE)
CODE_SPAN = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.DOTALL)
LINK = re.compile(
    r"(!?)\[((?:[^\[\]\\]|\\.|\[(?:[^\[\]\\]|\\.)*\])*)\]"  # [text], one level of nesting
    r"\(\s*(<[^<>\n]*>|[^\s()<>]*(?:\([^\s()]*\)[^\s()<>]*)*)"  # (target
    r"(?:\s+(?:\"[^\"]*\"|'[^']*'|\([^()]*\)))?\s*\)",  # optional "title")
    re.DOTALL,
)
REFERENCE = re.compile(r"^ {0,3}\[([^\]]+)\]:\s*(<[^<>]*>|\S+)", re.MULTILINE)
SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")
BUILD_DIRS = re.compile(r"^(build[^/]*|\.git|Testing)(/|$)")


def markdown_files(root: Path) -> list[Path]:
    try:
        out = subprocess.run(
            ["git", "-C", str(root), "ls-files", "-z", "--cached", "--others",
             "--exclude-standard", "--", "*.md"],
            check=True, capture_output=True, text=True).stdout
        names = sorted({n for n in out.split("\0") if n})
        return [root / n for n in names if (root / n).is_file()]
    except (OSError, subprocess.CalledProcessError):
        found = []
        for directory, dirs, files in os.walk(root):
            rel = Path(directory).relative_to(root).as_posix()
            dirs[:] = [d for d in dirs
                       if not BUILD_DIRS.match(d if rel == "." else f"{rel}/{d}")]
            found += [Path(directory) / f for f in files if f.endswith(".md")]
        return sorted(found)


def split_fences(lines: list[str]) -> list[bool]:
    """For each line, whether it belongs to a fenced code block (fence lines included)."""
    inside, fence_char, fence_len, flags = False, "", 0, []
    for line in lines:
        m = FENCE.match(line)
        if not inside and m:
            inside, fence_char, fence_len = True, m.group(1)[0], len(m.group(1))
            flags.append(True)
        elif inside:
            flags.append(True)
            if m and m.group(1)[0] == fence_char and len(m.group(1)) >= fence_len \
                    and not line.strip().strip(fence_char):
                inside = False
        else:
            flags.append(False)
    return flags


def heading_text(raw: str) -> str:
    """The text GitHub renders for a heading's Markdown source."""
    parts, pos = [], 0
    for m in CODE_SPAN.finditer(raw):
        parts.append(("md", raw[pos:m.start()]))
        parts.append(("code", m.group(2).strip() if m.group(2).strip() else m.group(2)))
        pos = m.end()
    parts.append(("md", raw[pos:]))
    text = ""
    for kind, part in parts:
        if kind == "md":
            part = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", part)  # links and images: text
            part = re.sub(r"<[^>]+>", "", part)  # HTML tags
            part = re.sub(r"\\(.)", r"\1", part)  # backslash escapes
            part = part.replace("*", "")
            part = re.sub(r"(?<![^\W_])_+|_+(?![^\W_])", "", part)  # _emphasis_, not snake_case
        text += part
    return text


def slug(text: str) -> str:
    text = text.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors_of(path: Path, cache: dict) -> set[str]:
    if path in cache:
        return cache[path]
    lines = path.read_text(encoding="utf-8", errors="replace").split("\n")
    fenced = split_fences(lines)
    seen: dict[str, int] = {}
    anchors: set[str] = set()

    def add(text: str) -> None:
        base = slug(heading_text(text))
        n = seen.get(base, 0)
        seen[base] = n + 1
        anchors.add(base if n == 0 else f"{base}-{n}")

    for i, line in enumerate(lines):
        if fenced[i]:
            continue
        for m in HTML_ANCHOR.finditer(line):
            anchors.add(m.group(1))
        m = ATX.match(line)
        if m:
            add(m.group(2) or "")
            continue
        # A setext heading: a paragraph line underlined with === or --- (not a table rule,
        # not after a blank line, list item or another heading).
        if i + 1 < len(lines) and not fenced[i + 1] and SETEXT.match(lines[i + 1]) \
                and line.strip() and not ATX.match(line) and "|" not in line \
                and not re.match(r"^\s*([-*+]|\d+[.)])\s", line):
            add(line.strip())
    cache[path] = anchors
    return anchors


def masked_text(text: str) -> str:
    """The text with fenced blocks and code spans blanked, line numbers kept."""
    lines = text.split("\n")
    fenced = split_fences(lines)
    kept = "\n".join("" if f else line for line, f in zip(lines, fenced))
    return CODE_SPAN.sub(lambda m: re.sub(r"[^\n]", "x", m.group(0)), kept)


def targets(text: str):
    """(offset, target) of every inline link, image and reference definition."""
    def scan(chunk: str, base: int):
        for m in LINK.finditer(chunk):
            yield base + m.start(3), m.group(3)
            yield from scan(m.group(2), base + m.start(2))  # [![badge](img)](page)
    yield from scan(text, 0)
    for m in REFERENCE.finditer(text):
        yield m.start(2), m.group(2)


def check_link(root: Path, source: Path, target: str, cache: dict) -> str | None:
    """None if the link is good, else why not."""
    target = target.strip()
    if target.startswith("<") and target.endswith(">"):
        target = target[1:-1].strip()
    if not target or SCHEME.match(target) or target.startswith("//"):
        return None
    path_part, _, anchor = target.partition("#")
    path_part = urllib.parse.unquote(path_part.split("?", 1)[0])
    anchor = urllib.parse.unquote(anchor)
    if not path_part:
        dest = source
    elif path_part.startswith("/"):
        dest = root / path_part.lstrip("/")
    else:
        dest = source.parent / path_part
    dest = Path(os.path.normpath(dest))
    try:
        dest.relative_to(root)
    except ValueError:
        return None  # outside the repository (../shared): not ours to check
    if not dest.exists():
        return "no such file"
    if not anchor or dest.is_dir() or dest.suffix.lower() != ".md":
        return None
    if anchor not in anchors_of(dest, cache):
        where = "in this file" if dest == source else f"in {dest.relative_to(root).as_posix()}"
        return f"no heading with this anchor {where}"
    return None


def main(argv: list[str]) -> int:
    if len(argv) > 2:
        print("usage: check_links.py [ROOT]", file=sys.stderr)
        return 2
    root = Path(os.path.abspath(argv[1] if len(argv) == 2 else ".")).resolve()
    files = markdown_files(root)
    if not files:
        print(f"check_links: no Markdown files under {root}", file=sys.stderr)
        return 2
    cache: dict = {}
    broken = checked = 0
    for source in files:
        text = masked_text(source.read_text(encoding="utf-8", errors="replace"))
        for offset, target in targets(text):
            why = check_link(root, source, target, cache)
            checked += 1
            if why:
                line = text.count("\n", 0, offset) + 1  # masking keeps the lines
                print(f"{source.relative_to(root).as_posix()}:{line}: {target} ({why})")
                broken += 1
    if broken:
        print(f"{broken} broken link(s) of {checked} in {len(files)} Markdown files")
        return 1
    print(f"{checked} links in {len(files)} Markdown files: all good")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
