#!/usr/bin/python3
"""Builds the Debian package with CPack into the build directory, where it stays, and checks
it: lintian, contents, control fields, maintainer scripts (statically and by what they do), a
real installation with dpkg into a scratch root, removal that keeps the configuration and purge
that does not, the installed programs and man pages, the udev rule, and the hardening of the
systemd unit (systemd-analyze security and verify).

Usage: package_test.py BUILD_DIR SOURCE_DIR VERSION [ARCH SYSROOT EMULATOR...]

The package is this machine's architecture's, or, for a cross build (cmake/debian-cross.cmake),
ARCH's: its dependencies must then be met by the packages of the sysroot (SYSROOT/DEBIAN/packages,
written by scripts/package), and the installed programs run under EMULATOR (qemu-user with the
sysroot's libraries).

Needs dpkg-dev (dpkg-shlibdeps), lintian, systemd (systemd-analyze), groff, man-db and
util-linux (unshare); scripts/install-deps installs them. Runs as root or not: dpkg gets
--force-not-root, and the maintainer scripts run in a user and mount namespace of their own.
"""

import gzip
import os
import re
import shutil
import stat
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from unit_file import unit_settings

BUILD_DIR, SOURCE_DIR, VERSION = (Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3])
CROSS = len(sys.argv) > 4
SYSROOT = Path(sys.argv[5]) if CROSS else None
EMULATOR = sys.argv[6:]
PACKAGING = SOURCE_DIR / "packaging"
UNIT = "ioportd.service"
MAX_EXPOSURE = 2.0

failures: list[str] = []
passed = 0


def check(condition: bool, message: str) -> bool:
    global passed
    if condition:
        passed += 1
    else:
        failures.append(message)
        print(f"FAIL: {message}", flush=True)
    return condition


def run(*args, env=None, stdin=subprocess.DEVNULL, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([str(a) for a in args], env=env, stdin=stdin, capture_output=True,
                          text=True, **kwargs)


def section(title: str) -> None:
    print(f"== {title}", flush=True)


# ---- The package, and what it must contain ---------------------------------------------------

ARCH = sys.argv[4] if CROSS else run("dpkg", "--print-architecture").stdout.strip()

# path -> mode string of `dpkg-deb -c`. Directories end with "/".
EXPECTED_FILES = {
    "./etc/": "drwxr-xr-x",
    "./etc/ioportd/": "drwxr-xr-x",
    "./etc/ioportd/ioportd.yaml": "-rw-r--r--",
    "./lib/": "drwxr-xr-x",
    "./lib/systemd/": "drwxr-xr-x",
    "./lib/systemd/system/": "drwxr-xr-x",
    "./lib/systemd/system/ioportd.service": "-rw-r--r--",
    "./lib/udev/": "drwxr-xr-x",
    "./lib/udev/rules.d/": "drwxr-xr-x",
    "./lib/udev/rules.d/70-ioportd.rules": "-rw-r--r--",
    "./usr/": "drwxr-xr-x",
    "./usr/bin/": "drwxr-xr-x",
    "./usr/bin/ioport-sim": "-rwxr-xr-x",
    "./usr/bin/ioportctl": "-rwxr-xr-x",
    "./usr/lib/": "drwxr-xr-x",
    "./usr/lib/modules-load.d/": "drwxr-xr-x",
    "./usr/lib/modules-load.d/ioportd.conf": "-rw-r--r--",
    "./usr/lib/sysusers.d/": "drwxr-xr-x",
    "./usr/lib/sysusers.d/ioportd.conf": "-rw-r--r--",
    "./usr/sbin/": "drwxr-xr-x",
    "./usr/sbin/ioportd": "-rwxr-xr-x",
    "./usr/share/": "drwxr-xr-x",
    "./usr/share/doc/": "drwxr-xr-x",
    "./usr/share/doc/ioportd/": "drwxr-xr-x",
    "./usr/share/doc/ioportd/README.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/configuration.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/faults.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/http.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/ioportctl.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/library.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/modbus.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/operations.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/simulator.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/sparkplug.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/tls.md.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/changelog.gz": "-rw-r--r--",
    "./usr/share/doc/ioportd/copyright": "-rw-r--r--",
    "./usr/share/man/": "drwxr-xr-x",
    "./usr/share/man/man1/": "drwxr-xr-x",
    "./usr/share/man/man1/ioport-sim.1.gz": "-rw-r--r--",
    "./usr/share/man/man1/ioportctl.1.gz": "-rw-r--r--",
    "./usr/share/man/man8/": "drwxr-xr-x",
    "./usr/share/man/man8/ioportd.8.gz": "-rw-r--r--",
}
BINARIES = ["usr/sbin/ioportd", "usr/bin/ioportctl", "usr/bin/ioport-sim"]
MAN_PAGES = ["usr/share/man/man8/ioportd.8.gz", "usr/share/man/man1/ioportctl.1.gz",
             "usr/share/man/man1/ioport-sim.1.gz"]
CONFFILE = "/etc/ioportd/ioportd.yaml"
# Libraries the binaries link, by Debian package name (prefixes where the name carries an ABI
# suffix that may change with a rebuild against another version).
# Each architecture's package names all of them: a library the linker took statically from a
# sysroot instead (libcrypt.a, once, for arm64 and armhf) is missing here.
EXPECTED_DEPENDS = ["libc6", "libstdc++6", "libgcc-s1", "libmodbus5", "libsystemd0",
                    "libyaml-cpp0.7", "libfmt9", "libspdlog1.10", "libcrypt1", "libssl3",
                    "libmosquitto1", "libprotobuf-lite32", "procps"]
SCRIPTS = ["postinst", "prerm", "postrm"]


def build_package() -> Path | None:
    """cpack in the build directory, as a person would: the package is left there."""
    section("cpack")
    deb = BUILD_DIR / f"ioportd_{VERSION}_{ARCH}.deb"
    deb.unlink(missing_ok=True)
    result = run("cpack", "--config", BUILD_DIR / "CPackConfig.cmake", "-B", BUILD_DIR)
    if not check(result.returncode == 0, f"cpack failed:\n{result.stdout}{result.stderr}"):
        return None
    if not check(deb.exists(), f"cpack did not write {deb}:\n{result.stdout}"):
        return None
    print(f"package: {deb}")
    return deb


def check_lintian(deb: Path) -> None:
    """Debian's own checks: no error and no warning (an overridden tag has its reason in the
    override); of its notes, none that a program lacks a hardening flag (hardening-no-*)."""
    section("lintian")
    result = run("lintian", "--fail-on", "error,warning", "--display-info", deb)
    notes = result.stdout.splitlines()
    check(result.returncode == 0 and all(line.startswith("I: ") for line in notes),
          f"lintian: exit {result.returncode}\n{result.stdout}{result.stderr}")
    unhardened = [line for line in notes if " hardening-" in line]
    check(not unhardened, "lintian: " + "\n".join(unhardened))


def check_contents(deb: Path) -> None:
    section("contents")
    listing = run("dpkg-deb", "-c", deb)
    check(listing.returncode == 0, f"dpkg-deb -c: {listing.stderr}")
    found: dict[str, str] = {}
    for line in listing.stdout.splitlines():
        fields = line.split(maxsplit=5)
        mode, owner, path = fields[0], fields[1], fields[5]
        found[path] = mode
        check(owner == "root/root", f"{path} is owned by {owner}, not root/root")
    missing = sorted(set(EXPECTED_FILES) - set(found))
    extra = sorted(set(found) - set(EXPECTED_FILES))
    check(not missing, f"missing from the package: {missing}")
    check(not extra, f"not expected in the package: {extra}")
    for path, mode in EXPECTED_FILES.items():
        if path in found:
            check(found[path] == mode, f"{path} has mode {found[path]}, expected {mode}")


def check_control(deb: Path) -> None:
    section("control fields")
    fields = {}
    for name in ["Package", "Version", "Architecture", "Maintainer", "Section", "Priority",
                 "Depends", "Description", "Installed-Size"]:
        value = run("dpkg-deb", "-f", deb, name).stdout.strip()
        fields[name] = value
        check(value != "", f"control field {name} is missing")
    check(fields["Package"] == "ioportd", f"Package: {fields['Package']}")
    check(fields["Version"] == VERSION, f"Version: {fields['Version']}, expected {VERSION}")
    check(fields["Architecture"] == ARCH, f"Architecture: {fields['Architecture']}")
    check(fields["Section"] == "net", f"Section: {fields['Section']}")
    check(re.fullmatch(r"[^<>]+ <[^<>@\s]+@[^<>@\s]+>", fields["Maintainer"]) is not None,
          f"Maintainer is not 'Name <address>': {fields['Maintainer']}")
    depends = [d.strip() for d in fields["Depends"].split(",")]
    names = [re.split(r"[\s(]", d, maxsplit=1)[0] for d in depends]
    for expected in EXPECTED_DEPENDS:
        check(any(n == expected or n.startswith(expected + "-") for n in names),
              f"Depends lacks {expected}: {fields['Depends']}")
    # Built here, so every dependency must be satisfiable here: apt install ./ioportd_*.deb on
    # this Debian release resolves. A cross build's, by the packages it was built against.
    installed = set()
    if CROSS:
        where = f"{SYSROOT}/DEBIAN/packages"
        query = (SYSROOT / "DEBIAN/packages").read_text()  # Package|Version|Architecture|Provides
        packages = [(fields[0], fields[3]) for fields in
                    (line.split("|") for line in query.splitlines())]
    else:
        where = "this machine"
        query = run("dpkg-query", "-W", "-f=${db:Status-Abbrev}|${Package}|${Provides}\n").stdout
        packages = [(package, provides) for state, package, provides in
                    (line.split("|") for line in query.splitlines()) if state.startswith("ii")]
    for package, provides in packages:
        installed.add(package)
        installed.update(re.split(r"\s*\([^)]*\)\s*|\s*,\s*", provides))
    for name in names:
        check(name in installed, f"Depends names {name}, which nothing in {where} provides")
    changelog = run("dpkg-parsechangelog", "-l", PACKAGING / "changelog", "-S", "Version")
    check(changelog.stdout.strip() == VERSION,
          f"packaging/changelog's latest entry is {changelog.stdout.strip()!r}, the project "
          f"version {VERSION}: add an entry for the new version")


def extract_control(deb: Path, into: Path) -> None:
    section("control archive")
    tar_bytes = subprocess.run(["dpkg-deb", "--ctrl-tarfile", str(deb)], capture_output=True,
                               check=True).stdout
    tar_path = into / "control.tar"
    tar_path.write_bytes(tar_bytes)
    with tarfile.open(tar_path) as tar:
        members = {m.name.removeprefix("./"): m for m in tar.getmembers() if m.isfile()}
        check(sorted(members) == sorted(["conffiles", "control", "md5sums"] + SCRIPTS),
              f"control archive holds {sorted(members)}")
        for name, member in members.items():
            expected = 0o755 if name in SCRIPTS else 0o644
            check(stat.S_IMODE(member.mode) == expected,
                  f"control member {name} has mode {oct(stat.S_IMODE(member.mode))}")
        tar.extractall(into / "control")  # dpkg-deb's own output, read back
    control = into / "control"
    conffiles = (control / "conffiles").read_text().split()
    check(conffiles == [CONFFILE], f"conffiles: {conffiles}")
    for script in SCRIPTS:
        path = control / script
        text = path.read_text()
        check(text.startswith("#!/bin/sh\n"), f"{script} does not start with #!/bin/sh")
        check("\nset -e\n" in text, f"{script} does not set -e")
        syntax = run("sh", "-n", path)
        check(syntax.returncode == 0 and syntax.stderr == "", f"sh -n {script}: {syntax.stderr}")
        if shutil.which("shellcheck"):
            lint = run("shellcheck", "-s", "sh", path)
            check(lint.returncode == 0, f"shellcheck {script}:\n{lint.stdout}")
    # md5sums covers every regular file of the package.
    sums = {line.split(maxsplit=1)[1] for line in (control / "md5sums").read_text().splitlines()}
    files = {p.removeprefix("./") for p, m in EXPECTED_FILES.items() if m.startswith("-")}
    check(sums == files, f"md5sums lists {sorted(sums)}")


# ---- What the maintainer scripts do ----------------------------------------------------------

STUBBED = ["systemctl", "deb-systemd-invoke", "udevadm", "modprobe", "systemd-sysusers"]


def make_stubs(directory: Path, log: Path, without: tuple[str, ...] = ()) -> None:
    """A PATH holding only logging stand-ins for the system tools the scripts may call, and rm
    (postrm purge)."""
    directory.mkdir(parents=True, exist_ok=True)
    for tool in STUBBED:
        if tool in without:
            continue
        stub = directory / tool
        stub.write_text(f'#!/bin/sh\necho "{tool} $*" >> "{log}"\n')
        stub.chmod(0o755)
    (directory / "rm").symlink_to(shutil.which("rm"))


def run_script(script: Path, args: list[str], *, systemd: bool, udev: bool,
               dpkg_root: str = "", without: tuple[str, ...] = ()
               ) -> tuple[subprocess.CompletedProcess, list[str]]:
    """Runs a maintainer script in a user and mount namespace whose /run is a fresh tmpfs,
    holding /run/systemd/system (systemd is running) and /run/udev (udev is running) as asked,
    with only the stubs on PATH. Returns the result and the stub calls."""
    with tempfile.TemporaryDirectory(prefix="ioportd-script-") as scratch:
        stubs, log = Path(scratch) / "bin", Path(scratch) / "calls"
        log.touch()
        make_stubs(stubs, log, without)
        dirs = (["/run/systemd/system"] if systemd else []) + (["/run/udev"] if udev else [])
        setup = "mount -t tmpfs tmpfs /run && " + "".join(f"mkdir -p {d} && " for d in dirs)
        env = {"PATH": str(stubs), "DPKG_ROOT": dpkg_root}
        assignments = " ".join(f"{k}='{v}'" for k, v in env.items())
        command = f"{setup}exec env -i {assignments} /bin/sh {script} " + " ".join(
            f"'{a}'" for a in args)
        result = run("unshare", "--user", "--map-root-user", "--mount", "/bin/sh", "-c", command)
        return result, log.read_text().splitlines()


def check_script_behaviour(control: Path) -> None:
    section("maintainer script behaviour")
    probe = run("unshare", "--user", "--map-root-user", "--mount", "/bin/sh", "-c",
                "mount -t tmpfs tmpfs /run")
    if not check(probe.returncode == 0,
                 f"cannot make a user and mount namespace (unshare -rm) to run the maintainer "
                 f"scripts in: {probe.stderr.strip()}"):
        return
    postinst, prerm, postrm = (control / s for s in SCRIPTS)
    reload_ = "systemctl --system daemon-reload"
    modules = "modprobe -a -b -q usbserial cdc_acm"
    udev_reload = "udevadm control --reload-rules"
    udev_trigger = "udevadm trigger --action=change --subsystem-match=usb-serial " \
                   "--subsystem-match=tty"
    group = "systemd-sysusers ioportd.conf"

    result, calls = run_script(postinst, ["configure"], systemd=True, udev=True)
    check(result.returncode == 0, f"postinst configure: exit {result.returncode} {result.stderr}")
    check(calls == [group, reload_, modules, udev_reload, udev_trigger],
          f"postinst configure (fresh install) called {calls}: it must make the group ioportd, "
          f"reload systemd and udev, load the serial drivers, and neither enable nor start the "
          f"service")
    check("systemctl enable --now ioportd" in result.stdout,
          f"postinst configure does not tell how to start the service: {result.stdout!r}")

    result, calls = run_script(postinst, ["configure", "0.0.9"], systemd=True, udev=True)
    check(result.returncode == 0 and calls == [group, reload_, modules, udev_reload, udev_trigger,
                                               f"deb-systemd-invoke try-restart {UNIT}"],
          f"postinst configure 0.0.9 (upgrade) called {calls}: it must try-restart the service")
    check(result.stdout == "", f"postinst on upgrade prints {result.stdout!r}")

    result, calls = run_script(postinst, ["configure"], systemd=False, udev=False)
    check(result.returncode == 0 and calls == [group],
          f"postinst configure without a running systemd and udev (a chroot) called {calls}: "
          f"only the group is made there")

    result, calls = run_script(postinst, ["configure", "0.0.9"], systemd=True, udev=True,
                               dpkg_root="/srv/image")
    check(result.returncode == 0 and calls == ["systemd-sysusers --root=/srv/image ioportd.conf"],
          f"postinst with DPKG_ROOT set must leave the host's systemd and udev alone and make "
          f"the group in the image: {calls}")

    result, calls = run_script(postinst, ["configure"], systemd=True, udev=True,
                               without=("systemd-sysusers",))
    check(result.returncode == 0 and calls[:1] == [reload_],
          f"postinst without systemd-sysusers (no systemd installed) called {calls}")

    result, calls = run_script(prerm, ["remove"], systemd=True, udev=True)
    check(result.returncode == 0 and calls == [f"deb-systemd-invoke stop {UNIT}"],
          f"prerm remove called {calls}: it must stop the service")
    result, calls = run_script(prerm, ["remove"], systemd=False, udev=False)
    check(result.returncode == 0 and calls == [], f"prerm remove without systemd: {calls}")
    result, calls = run_script(prerm, ["upgrade", "0.2.0"], systemd=True, udev=True)
    check(result.returncode == 0 and calls == [],
          f"prerm upgrade called {calls}: the service keeps running until postinst restarts it")

    for action in ["remove", "purge"]:
        result, calls = run_script(postrm, [action], systemd=True, udev=True)
        check(result.returncode == 0 and calls == [reload_, udev_reload],
              f"postrm {action} called {calls}")
    result, calls = run_script(postrm, ["upgrade", "0.2.0"], systemd=True, udev=True)
    check(result.returncode == 0 and calls == [], f"postrm upgrade called {calls}")

    for script in (postinst, prerm, postrm):
        result, calls = run_script(script, ["no-such-action"], systemd=True, udev=True)
        check(result.returncode == 1 and calls == [],
              f"{script.name} no-such-action: exit {result.returncode}, calls {calls}")


# ---- A real installation ---------------------------------------------------------------------

def dpkg(root: Path, stubs: Path, *args) -> subprocess.CompletedProcess:
    # The stubs come first on PATH: with DPKG_ROOT set, the scripts must call none of them.
    env = dict(os.environ, PATH=f"{stubs}:{os.environ['PATH']}")
    foreign = ["--force-architecture"] if CROSS else []
    return run("dpkg", f"--root={root}", "--force-script-chrootless", "--force-depends",
               "--force-not-root", *foreign, "--log=/dev/null", *args, env=env)


def status(root: Path) -> str:
    result = run("dpkg-query", f"--root={root}", "-W", "-f=${Status}", "ioportd")
    return result.stdout if result.returncode == 0 else "not known"


def check_installation(deb: Path, scratch: Path) -> Path | None:
    section("dpkg --root install, remove, purge")
    root = scratch / "root"
    for d in ["var/lib/dpkg/info", "var/lib/dpkg/updates", "var/lib/dpkg/triggers", "var/log"]:
        (root / d).mkdir(parents=True)
    (root / "var/lib/dpkg/status").touch()
    stubs, log = scratch / "stubs", scratch / "calls"
    log.touch()
    make_stubs(stubs, log)

    result = dpkg(root, stubs, "-i", deb)
    if not check(result.returncode == 0, f"dpkg -i: {result.stdout}{result.stderr}"):
        return None
    check(status(root) == "install ok installed", f"after dpkg -i: {status(root)}")
    for path, mode in EXPECTED_FILES.items():
        installed = root / path
        if not check(installed.exists(), f"{path} is not installed"):
            continue
        actual = installed.stat().st_mode
        check(stat.filemode(actual) == mode, f"{path} is installed {stat.filemode(actual)}")
    conffiles = run("dpkg-query", f"--root={root}", "-W", "-f=${Conffiles}", "ioportd").stdout
    check(CONFFILE in conffiles, f"dpkg does not know {CONFFILE} as a conffile: {conffiles!r}")
    check((root / "etc/ioportd/ioportd.yaml").read_bytes() ==
          (SOURCE_DIR / "config/ioportd.yaml").read_bytes(),
          "the installed configuration is not config/ioportd.yaml")
    for binary in BINARIES:
        sections = run("readelf", "-S", "-W", root / binary).stdout
        check(".debug_info" not in sections, f"{binary} is not stripped")
    # A second installation of the same version over a changed configuration keeps the change
    # and asks nothing (stdin is /dev/null: a prompt would fail).
    config = root / "etc/ioportd/ioportd.yaml"
    config.write_text(config.read_text() + "# changed by the integrator\n")
    result = dpkg(root, stubs, "-i", deb)
    check(result.returncode == 0, f"dpkg -i over a changed configuration: {result.stderr}")
    check(config.read_text().endswith("# changed by the integrator\n"),
          "reinstalling the package replaced the changed configuration")
    check(set(log.read_text().splitlines()) <= {f"systemd-sysusers --root={root} ioportd.conf"},
          f"the scripts called {log.read_text()!r} with DPKG_ROOT set: only the group may be "
          f"made, in the image")
    log.write_text("")  # removal and purge must call nothing at all
    # What the stub stood for, for real in the image: the unit's SupplementaryGroups= exists.
    made = run("systemd-sysusers", f"--root={root}", root / "usr/lib/sysusers.d/ioportd.conf")
    check(made.returncode == 0 and re.search(r"^ioportd:x:\d+:$",
                                             (root / "etc/group").read_text(), re.M) is not None,
          f"systemd-sysusers with the package's ioportd.conf made no group ioportd: "
          f"{made.stderr}")
    return root


def check_remove_and_purge(root: Path, scratch: Path) -> None:
    stubs = scratch / "stubs"
    config = root / "etc/ioportd/ioportd.yaml"
    # What "systemctl enable ioportd" and the integrator leave behind.
    wants = root / "etc/systemd/system/multi-user.target.wants"
    wants.mkdir(parents=True)
    (wants / UNIT).symlink_to(f"/lib/systemd/system/{UNIT}")
    (root / "etc/ioportd/ioportd.yaml.before-commissioning").write_text("modbus: {}\n")

    result = dpkg(root, stubs, "-r", "ioportd")
    check(result.returncode == 0, f"dpkg -r: {result.stdout}{result.stderr}")
    check(status(root) == "deinstall ok config-files", f"after dpkg -r: {status(root)}")
    for path, mode in EXPECTED_FILES.items():
        if not mode.startswith("d") and path != "./etc/ioportd/ioportd.yaml":
            check(not (root / path).exists(), f"dpkg -r left {path}")
    check(config.exists() and config.read_text().endswith("# changed by the integrator\n"),
          "dpkg -r did not keep the configuration")
    check((wants / UNIT).is_symlink(), "dpkg -r removed the enablement link")

    result = dpkg(root, stubs, "--purge", "ioportd")
    check(result.returncode == 0, f"dpkg --purge: {result.stdout}{result.stderr}")
    check(status(root) in ("not known", "unknown ok not-installed"),
          f"after dpkg --purge: {status(root)}")
    left = sorted(p.name for p in (root / "etc/ioportd").glob("*"))
    check(not (root / "etc/ioportd").exists(), f"dpkg --purge left /etc/ioportd: {left}")
    check(not (wants / UNIT).is_symlink(), "dpkg --purge left the enablement link")
    check(wants.is_dir(), "dpkg --purge removed a directory of systemd's")
    check((scratch / "calls").read_text() == "",
          f"the scripts called {(scratch / 'calls').read_text()!r} with DPKG_ROOT set")


# ---- The installed programs, man pages, udev rule and unit -----------------------------------

def check_programs(root: Path) -> None:
    section("installed programs")
    ioportd = root / "usr/sbin/ioportd"
    config = root / "etc/ioportd/ioportd.yaml"
    result = run(*EMULATOR, ioportd, "--check-config", "--config", config)
    check(result.returncode == 0 and f"{config}: valid" in result.stdout,
          f"ioportd --check-config on the installed configuration: exit {result.returncode}\n"
          f"{result.stdout}{result.stderr}")
    result = run(*EMULATOR, ioportd, "--version")
    check(result.returncode == 0 and result.stdout.strip() == f"ioportd {VERSION}",
          f"ioportd --version: {result.stdout!r}")
    for binary in BINARIES:
        result = run(*EMULATOR, root / binary, "--help")
        check(result.returncode == 0 and result.stdout.startswith("Usage:"),
              f"{binary} --help: exit {result.returncode}, {result.stdout[:80]!r}")


def check_hardening(root: Path) -> None:
    """What Debian's hardening flags leave in a program (CMakeLists.txt, IOPORTD_HARDENING), read
    from the ELF file itself: position independent, every symbol bound at start and the GOT then
    read-only (full RELRO), stack canaries, and glibc's checked functions (_FORTIFY_SOURCE)."""
    section("hardening")
    for binary in BINARIES:
        elf = run("readelf", "--wide", "--dynamic", "--program-headers", "--dyn-syms",
                  root / binary)
        if not check(elf.returncode == 0, f"readelf {binary}: {elf.stderr}"):
            continue
        flags = " ".join(re.findall(r"\(FLAGS(?:_1)?\)\s+(?:Flags: )?(.*)", elf.stdout))
        symbols = set(re.findall(r"\b(__\w+_chk(?:_fail)?)\b", elf.stdout))
        check("PIE" in flags.split(), f"{binary}: not position independent ({flags!r})")
        check("NOW" in flags.split() or "BIND_NOW" in flags.split(),
              f"{binary}: symbols bound lazily, not at start ({flags!r})")
        check("GNU_RELRO" in elf.stdout, f"{binary}: no RELRO segment")
        check("__stack_chk_fail" in symbols, f"{binary}: no stack protector")
        check(symbols - {"__stack_chk_fail"}, f"{binary}: no checked (fortified) function")


def check_man_pages(root: Path) -> None:
    section("man pages")
    for page in MAN_PAGES:
        text = gzip.decompress((root / page).read_bytes()).decode()
        check("@PROJECT_VERSION@" not in text and f"ioportd {VERSION}" in text,
              f"{page} does not carry the version {VERSION}")
        result = run("groff", "-man", "-ww", "-z", input=text, stdin=None)
        check(result.returncode == 0 and result.stderr == "",
              f"groff -man -ww -z {page}:\n{result.stderr}")
    # Every option of ioportd --help is in the man page.
    usage = run(*EMULATOR, root / "usr/sbin/ioportd", "--help").stdout
    page = gzip.decompress((root / MAN_PAGES[0]).read_bytes()).decode().replace("\\-", "-")
    for option in sorted(set(re.findall(r"(?<![\w-])--[a-z][a-z-]+", usage))):
        check(option in page, f"ioportd --help has {option}, ioportd(8) does not")


UDEV_MATCH = {"ACTION", "DEVPATH", "KERNEL", "KERNELS", "NAME", "SYMLINK", "SUBSYSTEM",
              "SUBSYSTEMS", "DRIVER", "DRIVERS", "ATTR", "ATTRS", "SYSCTL", "ENV", "CONST",
              "TAG", "TAGS", "TEST", "PROGRAM", "RESULT"}
UDEV_ASSIGN = {"NAME", "SYMLINK", "OWNER", "GROUP", "MODE", "SECLABEL", "ATTR", "SYSCTL",
               "ENV", "TAG", "RUN", "LABEL", "GOTO", "IMPORT", "OPTIONS"}
UDEV_WITH_ATTRIBUTE = {"ATTR", "ATTRS", "SYSCTL", "ENV", "CONST", "TEST", "IMPORT", "RUN",
                       "SECLABEL"}
UDEV_TOKEN = re.compile(r'\s*([A-Z]+)(?:\{([^}]+)\})?\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*(,|$)')


def check_udev_rule(root: Path) -> None:
    """udev 252 has no "udevadm verify": the rule is parsed here by udev's grammar (key,
    optional {attribute}, operator, quoted value, commas), keys and operators checked against
    udev(7), GOTO targets against LABELs; then what it must do."""
    section("udev rule")
    rules = (root / "lib/udev/rules.d/70-ioportd.rules").read_text()
    labels, gotos, parsed = set(), [], []
    for number, line in enumerate(rules.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tokens, position = [], 0
        while position < len(line):
            token = UDEV_TOKEN.match(line, position)
            if not check(token is not None, f"70-ioportd.rules:{number}: cannot parse "
                                            f"{line[position:]!r}"):
                break
            key, attribute, operator, value, _ = token.groups()
            is_match = operator in ("==", "!=")
            check(key in (UDEV_MATCH if is_match else UDEV_ASSIGN),
                  f"70-ioportd.rules:{number}: {key} does not take {operator}")
            check((attribute is not None) == (key in UDEV_WITH_ATTRIBUTE) or key == "IMPORT",
                  f"70-ioportd.rules:{number}: {key}{{{attribute}}}")
            for substitution in re.findall(r"\$(\w+)\{([^}]*)\}", value):
                check(substitution[0] in ("env", "attr") and substitution[1] != "",
                      f"70-ioportd.rules:{number}: substitution ${substitution[0]}{{...}}")
            if key == "LABEL":
                labels.add(value)
            if key == "GOTO":
                gotos.append((number, value))
            tokens.append((key, attribute, operator, value))
            position = token.end()
        parsed.append(tokens)
    for number, target in gotos:
        check(target in labels, f"70-ioportd.rules:{number}: GOTO {target} has no LABEL")

    def rule_with(*wanted):
        return [r for r in parsed if all(w in r for w in wanted)]

    check(bool(rule_with(("SUBSYSTEM", None, "==", "usb-serial"),
                         ("DRIVER", None, "==", "ftdi_sio"),
                         ("ATTR", "latency_timer", "=", "1"))),
          "no rule sets latency_timer 1 on ftdi_sio usb-serial devices")
    check(bool(rule_with(("ATTRS", "idVendor", "==", "0403"),
                         ("ATTRS", "idProduct", "==", "6001|6010|6011|6014|6015"))),
          "no rule matches the FTDI 0403:6001/6010/6011/6014/6015 adapters")
    check(bool(rule_with(("GROUP", None, "=", "dialout"))) and
          bool(rule_with(("MODE", None, "=", "0660"))), "no rule sets dialout and 0660")
    links = [t[3] for r in parsed for t in r if t[0] == "SYMLINK"]
    check(bool(links) and all(link.startswith("ioport/hub8u-$env{ID_SERIAL_SHORT}")
                              for link in links),
          f"the stable names are {links}")
    modules = (root / "usr/lib/modules-load.d/ioportd.conf").read_text().split("\n")
    modules = [m for m in modules if m and not m.startswith("#")]
    check(modules == ["usbserial", "cdc_acm"], f"modules-load.d/ioportd.conf: {modules}")


def check_unit(root: Path, scratch: Path) -> None:
    section("systemd unit")
    unit = root / "lib/systemd/system" / UNIT
    settings = unit_settings(unit)
    expected = {
        "Type": ["notify"], "NotifyAccess": ["main"], "Restart": ["on-failure"],
        "ExecStart": ["/usr/sbin/ioportd --config /etc/ioportd/ioportd.yaml"],
        "ExecReload": ["/bin/kill -HUP $MAINPID"],
        "DynamicUser": ["yes"], "SupplementaryGroups": ["dialout ioportd"],
        "AmbientCapabilities": ["CAP_NET_BIND_SERVICE"],
        "CapabilityBoundingSet": ["CAP_NET_BIND_SERVICE"],
        "NoNewPrivileges": ["yes"], "ProtectSystem": ["strict"], "ProtectHome": ["yes"],
        "PrivateTmp": ["yes"], "DevicePolicy": ["closed"],
        "RestrictAddressFamilies": ["AF_INET AF_INET6 AF_UNIX"],
        "MemoryDenyWriteExecute": ["yes"], "UMask": ["0077"], "WantedBy": ["multi-user.target"],
    }
    for key, values in expected.items():
        check(settings.get(key) == values, f"{UNIT}: {key}={settings.get(key)}, want {values}")
    check(all(re.fullmatch(r"char-tty[A-Z]+ rw", d) for d in settings.get("DeviceAllow", [])),
          f"{UNIT}: DeviceAllow= must name serial tty groups only: {settings.get('DeviceAllow')}")
    check("char-ttyUSB rw" in settings.get("DeviceAllow", []), f"{UNIT}: no DeviceAllow for ttyUSB")
    check(bool(settings.get("SystemCallFilter")), f"{UNIT}: no SystemCallFilter=")
    watchdog = settings.get("WatchdogSec", ["0"])[0]
    check(re.fullmatch(r"(1\d|2\d|30)s", watchdog) is not None,
          f"{UNIT}: WatchdogSec={watchdog}, want 10s-30s")
    # A backstop against a runaway allocation (a flood that some bound missed), well above the
    # measured peaks that the unit's comment lists.
    memory_max = settings.get("MemoryMax", ["infinity"])[0]
    check(re.fullmatch(r"\d+M", memory_max) is not None and 128 <= int(memory_max[:-1]) <= 1024,
          f"{UNIT}: MemoryMax={memory_max}, want 128M-1024M")
    check(settings.get("PrivateUsers") is None and settings.get("PrivateDevices") is None,
          f"{UNIT}: PrivateUsers=/PrivateDevices= would break port 502 or the serial ports")

    security = run("systemd-analyze", "security", "--offline=true", unit)
    check(security.stderr == "", f"systemd-analyze security warns:\n{security.stderr}")
    overall = re.search(r"Overall exposure level for ioportd\.service: (\d+\.\d+)",
                        security.stdout)
    if check(overall is not None, f"no overall exposure in:\n{security.stdout[-500:]}"):
        exposure = float(overall.group(1))
        print(f"systemd-analyze security --offline=true: overall exposure {exposure}")
        check(exposure <= MAX_EXPOSURE, f"overall exposure {exposure} > {MAX_EXPOSURE}:\n"
              + "\n".join(l for l in security.stdout.splitlines() if l.startswith("✗")))

    # verify wants ExecStart= to exist: a copy of the unit whose only change is that it runs
    # the binary installed in the scratch root. Documentation=man:ioportd(8) is looked up in
    # the scratch root's man pages.
    copy = scratch / "verify" / UNIT
    copy.parent.mkdir()
    text = unit.read_text()
    copy.write_text(text.replace("ExecStart=/usr/sbin/ioportd ",
                                 f"ExecStart={root}/usr/sbin/ioportd ", 1))
    check(copy.read_text() != text, "ExecStart= not found in the unit")
    env = dict(os.environ, MANPATH=f"{root}/usr/share/man")
    verify = run("systemd-analyze", "verify", copy, env=env)
    check(verify.returncode == 0 and verify.stdout == "" and verify.stderr == "",
          f"systemd-analyze verify: exit {verify.returncode}\n{verify.stdout}{verify.stderr}")


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="ioportd-package-") as scratch_name:
        scratch = Path(scratch_name)
        deb = build_package()
        if deb is not None:
            check_lintian(deb)
            check_contents(deb)
            check_control(deb)
            extract_control(deb, scratch)
            check_script_behaviour(scratch / "control")
            root = check_installation(deb, scratch)
            if root is not None:
                check_programs(root)
                check_hardening(root)
                check_man_pages(root)
                check_udev_rule(root)
                check_unit(root, scratch)
                check_remove_and_purge(root, scratch)
    print(f"package: {passed} passed, {len(failures)} failed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
