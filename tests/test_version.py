"""One version number: pyproject.toml's, which quadnav_onboard.__version__ reports and CHANGELOG.md
follows."""

from __future__ import annotations

import re
from pathlib import Path

import quadnav_onboard

REPO = Path(__file__).resolve().parent.parent


def _key(version: str) -> tuple[int, ...]:
    return tuple(int(p) for p in version.split("."))


def test_package_version_is_pyproject_s() -> None:
    """__version__ is the number written in pyproject.toml, in MAJOR.MINOR.PATCH form."""
    text = (REPO / "pyproject.toml").read_text(encoding="utf-8")
    project = text.split("[project]", 1)[1].split("\n[", 1)[0]  # the [project] table (3.10: no tomllib)
    version = re.search(r'(?m)^version = "([^"]+)"$', project).group(1)  # type: ignore[union-attr]
    assert re.fullmatch(r"\d+\.\d+\.\d+", version)
    assert quadnav_onboard.__version__ == version


def test_changelog_follows_the_version() -> None:
    """CHANGELOG.md's newest entry is this version, or "Unreleased" above older versions only;
    no entry names a version newer than pyproject.toml's."""
    version = quadnav_onboard.__version__
    text = (REPO / "CHANGELOG.md").read_text(encoding="utf-8")
    headings = re.findall(r"^## (\S+) \((\d{4}-\d{2}-\d{2})\)$", text, re.MULTILINE)
    assert headings, "CHANGELOG.md has no '## VERSION (YYYY-MM-DD)' entries"
    released = [v for v, _ in headings if v != "Unreleased"]
    assert all(re.fullmatch(r"\d+\.\d+\.\d+", v) for v in released), released
    assert released == sorted(released, key=_key, reverse=True), "entries newest first"
    assert _key(released[0]) <= _key(version)
    if headings[0][0] != "Unreleased":
        assert headings[0][0] == version
    else:
        assert _key(released[0]) < _key(version), "the unreleased entry is the next version"
