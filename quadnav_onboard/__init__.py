"""quadnav-onboard: end-to-end DQN motion planning for quadrotors, flown through PX4.

The pure core shared by training and flight: :mod:`frames`, :mod:`path`, :mod:`primitives`,
:mod:`reward`, :mod:`network`, :mod:`checkpoint`, :mod:`preprocess`, :mod:`config`.

``__version__`` has one source, ``version`` in pyproject.toml (CHANGELOG.md follows it): read from
the file in a source checkout (an editable install's metadata keeps the number it was installed
with), from the installed package's metadata otherwise.
"""

from __future__ import annotations

import re
from importlib import metadata
from pathlib import Path

__all__ = ["__version__"]


def _version() -> str:
    pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
    try:
        text = pyproject.read_text(encoding="utf-8")
    except OSError:
        text = ""
    if re.search(r'(?m)^name = "quadnav"$', text):
        match = re.search(r'(?m)^version = "([^"]+)"$', text)
        if match:
            return match.group(1)
    try:
        return metadata.version("quadnav")
    except metadata.PackageNotFoundError:
        return "0+unknown"


__version__ = _version()
