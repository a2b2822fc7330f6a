#!/usr/bin/env python3
"""Check the systemd unit and its snippets without a running systemd (CI, containers, laptops).

1. ``systemd-analyze verify``: the unit parses, with *no* warnings (systemd-analyze only warns
   about unknown keys or bad values and still exits 0; here any output is a failure). verify also
   needs the ExecStart binary to exist, so it runs on a temporary copy whose ExecStart points at
   the ``quadnav-onboard`` console script of this environment (same arguments).
2. ``systemd-analyze security --offline=true``: the exposure score must be <= ``--max-exposure``
   (default 2.0, "OK").
3. ``systemd-sysusers`` and ``systemd-tmpfiles --create`` on the snippets, inside a temporary root.

Usage:  python scripts/check_systemd_unit.py [--unit systemd/quadnav.service] [--max-exposure 2.0]
Exit status: 0 all checks pass, 1 a check failed, 2 the tools are missing or the unit is unreadable.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["CheckResult", "check_unit", "exposure_score", "main", "snippet_problems", "verify_problems"]

REPO = Path(__file__).resolve().parent.parent
DEFAULT_UNIT = REPO / "systemd" / "quadnav.service"
_SCORE_RE = re.compile(r"Overall exposure level for \S+: ([0-9]+(?:\.[0-9]+)?)")


class ToolMissingError(RuntimeError):
    """A systemd tool this check needs is not installed."""


@dataclass
class CheckResult:
    """What the checks found."""

    unit: str
    exposure: float | None = None
    max_exposure: float = 2.0
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def _tool(name: str) -> str:
    path = shutil.which(name) or (f"/usr/bin/{name}" if Path(f"/usr/bin/{name}").exists() else None)
    if path is None:
        raise ToolMissingError(f"{name} not found (install systemd; Debian/Ubuntu: apt-get install systemd)")
    return path


def _default_exec() -> Path:
    here = Path(sys.executable).parent / "quadnav-onboard"
    found = shutil.which("quadnav-onboard")
    return here if here.exists() else Path(found) if found else here


def _run(cmd: list[str], cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60, cwd=cwd, check=False)


def _exec_start_binary(text: str) -> str | None:
    m = re.search(r"^ExecStart=[-@:+!]*(\S+)", text, flags=re.MULTILINE)
    return m.group(1) if m else None


def verify_problems(unit: Path, exec_path: Path) -> list[str]:
    """Run ``systemd-analyze verify`` on a copy of ``unit`` whose ExecStart binary is ``exec_path``."""
    text = unit.read_text(encoding="utf-8")
    binary = _exec_start_binary(text)
    if binary is None:
        return [f"{unit}: no ExecStart= line"]
    if not exec_path.exists():
        return [f"{exec_path}: console script not found (pip install -e . first, or pass --exec)"]
    with tempfile.TemporaryDirectory(prefix="quadnav-unit-") as tmp:
        copy = Path(tmp) / unit.name
        copy.write_text(text.replace(f"ExecStart={binary}", f"ExecStart={exec_path}", 1), encoding="utf-8")
        proc = _run([_tool("systemd-analyze"), "verify", str(copy)], cwd=Path(tmp))
    out = (proc.stdout + proc.stderr).replace(str(copy), str(unit)).strip()
    problems = [f"verify: {line}" for line in out.splitlines() if line.strip()]
    if proc.returncode != 0 and not problems:
        problems.append(f"verify: systemd-analyze exited {proc.returncode}")
    return problems


def exposure_score(unit: Path) -> float:
    """The unit's ``systemd-analyze security --offline=true`` exposure (0 safe .. 10 exposed)."""
    cmd = [_tool("systemd-analyze"), "security", "--offline=true", str(unit.resolve())]
    proc = _run(cmd, cwd=unit.parent)
    m = _SCORE_RE.search(proc.stdout + proc.stderr)
    if m is None:
        raise RuntimeError(f"systemd-analyze security printed no score:\n{proc.stdout}{proc.stderr}")
    return float(m.group(1))


def snippet_problems(sysusers: Path | None, tmpfiles: Path | None) -> list[str]:
    """Apply the sysusers and tmpfiles snippets to an empty temporary root; report what fails."""
    problems: list[str] = []
    with tempfile.TemporaryDirectory(prefix="quadnav-root-") as tmp:
        root = Path(tmp)
        (root / "etc").mkdir()
        for name in ("passwd", "group", "shadow", "gshadow"):
            (root / "etc" / name).touch()
        for src, kind in ((sysusers, "sysusers"), (tmpfiles, "tmpfiles")):
            if src is None:
                continue
            dest = root / "usr" / "lib" / f"{kind}.d" / "quadnav.conf"
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dest)
            args = ["--create"] if kind == "tmpfiles" else []
            proc = _run([_tool(f"systemd-{kind}"), f"--root={root}", *args])
            if proc.returncode != 0:
                problems.append(f"{src}: systemd-{kind} failed: {(proc.stdout + proc.stderr).strip()}")
        if sysusers is not None and "quadnav:" not in (root / "etc" / "passwd").read_text():
            problems.append(f"{sysusers}: did not create the user 'quadnav'")
    return problems


def check_unit(unit: Path, *, max_exposure: float = 2.0, exec_path: Path | None = None) -> CheckResult:
    """Run all checks on ``unit`` (and the sysusers/tmpfiles snippets beside it, if present)."""
    result = CheckResult(unit=str(unit), max_exposure=max_exposure)
    result.problems += verify_problems(unit, exec_path or _default_exec())
    result.exposure = exposure_score(unit)
    if result.exposure > max_exposure:
        result.problems.append(f"security: exposure {result.exposure} > {max_exposure}")
    sysusers, tmpfiles = unit.with_suffix(".sysusers.conf"), unit.with_suffix(".tmpfiles.conf")
    result.problems += snippet_problems(
        sysusers if sysusers.exists() else None, tmpfiles if tmpfiles.exists() else None
    )
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--unit", type=Path, default=DEFAULT_UNIT, help="default systemd/quadnav.service")
    p.add_argument("--max-exposure", type=float, default=2.0, help="fail above this score (default 2.0)")
    p.add_argument("--exec", dest="exec_path", type=Path, help="ExecStart binary to verify against")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    args = p.parse_args(argv)
    if not args.unit.is_file():
        print(f"{args.unit}: no such unit file", file=sys.stderr)
        return 2
    try:
        result = check_unit(args.unit, max_exposure=args.max_exposure, exec_path=args.exec_path)
    except ToolMissingError as exc:
        print(f"check_systemd_unit: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({**result.__dict__, "ok": result.ok}))
    else:
        for problem in result.problems:
            print(f"FAIL {problem}")
        verdict = "OK" if result.ok else "FAILED"
        print(f"{result.unit}: exposure {result.exposure} (max {result.max_exposure}): {verdict}")
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
