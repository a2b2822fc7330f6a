#!/usr/bin/env python3
"""Check that quadnav's runtime dependencies install on the companion computer: ARM64 Linux, CPython 3.10.

Resolves ``[project].dependencies`` of pyproject.toml, plus the torch pin of the Makefile
(``TORCH_PIN``), for a foreign target from an x86-64 machine, wheels only (a source build on a
Jetson is what this check exists to rule out)::

    pip install --dry-run --ignore-installed --target TMP --only-binary=:all: \\
        --implementation cp --python-version 3.10 --abi cp310 \\
        --platform manylinux2014_aarch64 --platform manylinux_2_17_aarch64 ... manylinux_2_35_aarch64 \\
        --report REPORT.json <dependencies> torch==2.13.0

``--dry-run`` with ``--report`` resolves from the index's metadata without downloading the wheels
(torch and its CUDA libraries are GBs). The glibc ceiling defaults to 2.35, Ubuntu 22.04's, on which
JetPack 6 is built. The ``mocap`` extra (motioncapture) is left out: it has no ARM64 wheel and is
built from source (docs/hardware.md, section 1).

Prints one line per resolved distribution with its wheel; exits 1 when the resolution fails (pip's
message says which requirement) or a wheel is not for the target, 2 on bad arguments.

Usage: python3 scripts/check_target_deps.py [--python-version 3.10] [--arch aarch64] [--glibc 2.35]
       [--with REQ ...]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

REPO = Path(__file__).resolve().parent.parent
LEFT_OUT = {"motioncapture"}
"""Runtime requirements never resolved here (built from source on ARM64)."""


def runtime_requirements(pyproject: Path) -> list[str]:
    """``[project].dependencies`` of ``pyproject``, less :data:`LEFT_OUT`."""
    deps = tomllib.loads(pyproject.read_text())["project"]["dependencies"]
    return [d for d in deps if re.split(r"[\s<>=!~;\[]", d, maxsplit=1)[0].lower() not in LEFT_OUT]


def torch_pin(makefile: Path) -> str:
    """The Makefile's ``TORCH_PIN := torch==X`` (the torch CI and the docs install)."""
    m = re.search(r"^TORCH_PIN\s*:?=\s*(\S+)\s*$", makefile.read_text(), re.MULTILINE)
    if m is None:
        raise SystemExit(f"check_target_deps: {makefile}: no 'TORCH_PIN := torch==...' line")
    return m.group(1)


def platform_tags(arch: str, glibc: str) -> list[str]:
    """manylinux2014 and every manylinux_2_N from 2_17 up to ``glibc`` for ``arch``."""
    major, _, minor = glibc.partition(".")
    if major != "2" or not minor.isdigit() or int(minor) < 17:
        raise SystemExit(f"check_target_deps: --glibc {glibc!r}: expected 2.N with N >= 17")
    return [f"manylinux2014_{arch}"] + [f"manylinux_2_{n}_{arch}" for n in range(17, int(minor) + 1)]


def wheel_is_for_target(filename: str, arch: str) -> bool:
    """A pure-Python wheel, or one whose platform tag names ``arch``."""
    if not filename.endswith(".whl"):
        return False
    platform = filename[: -len(".whl")].split("-")[-1]
    return platform == "any" or all(p.endswith("_" + arch) for p in platform.split("."))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--python-version", default="3.10", help="target CPython (JetPack 6: 3.10)")
    p.add_argument("--arch", default="aarch64", help="target machine (manylinux tag suffix)")
    p.add_argument("--glibc", default="2.35", help="target glibc (Ubuntu 22.04 / JetPack 6: 2.35)")
    p.add_argument(
        "--with", dest="extra", action="append", default=[], metavar="REQ",
        help="also resolve this requirement (e.g. --with motioncapture shows the source-only one fail)",
    )  # fmt: skip
    args = p.parse_args(argv)
    if not re.fullmatch(r"3\.\d+", args.python_version):
        print(f"check_target_deps: --python-version {args.python_version!r}: expected 3.N", file=sys.stderr)
        return 2
    reqs = [*runtime_requirements(REPO / "pyproject.toml"), torch_pin(REPO / "Makefile"), *args.extra]
    py = args.python_version.replace(".", "")
    plats = [f for tag in platform_tags(args.arch, args.glibc) for f in ("--platform", tag)]
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="quadnav-target-") as tmp:
        report = Path(tmp) / "report.json"
        cmd = [
            sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
            "--target", str(Path(tmp) / "target"), "--only-binary=:all:",
            "--implementation", "cp", "--python-version", args.python_version, "--abi", f"cp{py}",
            *plats, "--report", str(report), *reqs,
        ]  # fmt: skip
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        elapsed_s = time.monotonic() - t0
        target = f"cp{py} manylinux (glibc <= {args.glibc}) {args.arch}"
        if proc.returncode != 0:
            noise = re.compile(r"^WARNING: Location '.*' is ignored")
            lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if not noise.match(ln)]
            print("\n".join(lines[-30:]), file=sys.stderr)
            print(
                f"check_target_deps: FAILED: the runtime dependencies do not resolve for {target}",
                file=sys.stderr,
            )
            return 1
        installs = json.loads(report.read_text())["install"]
    bad = []
    for item in sorted(installs, key=lambda i: i["metadata"]["name"].lower()):
        wheel = item["download_info"]["url"].rsplit("/", 1)[-1]
        print(f"  {item['metadata']['name']:<28} {item['metadata']['version']:<14} {wheel}")
        if not wheel_is_for_target(wheel, args.arch):
            bad.append(wheel)
    if bad:
        print(f"check_target_deps: FAILED: not wheels for {args.arch}: {', '.join(bad)}", file=sys.stderr)
        return 1
    print(
        f"check_target_deps: {len(installs)} distributions resolve to wheels for {target} "
        f"({len(reqs)} requirements) in {elapsed_s:.0f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
