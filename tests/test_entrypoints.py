"""The console scripts exist after install and answer --help."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.parametrize("script", ["quadnav-onboard", "quadnav-sim", "quadnav-review"])
def test_console_script_help(script):
    beside = Path(sys.executable).parent / script
    exe = str(beside) if beside.exists() else shutil.which(script)
    assert exe, f"{script} is not installed on PATH"
    out = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "usage:" in out.stdout
