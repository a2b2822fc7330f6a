#!/usr/bin/env python3
"""Screenshot an HTML report with headless Chromium and check the PNG is not blank.

    python scripts/screenshot_report.py REPORT.html OUT.png [--height 6000] [--chromium PATH]
    python scripts/screenshot_report.py --demo OUT_DIR   # synthetic flight -> report -> PNG

Needs Debian's ``chromium`` package (``apt-get install -y chromium``; binary /usr/bin/chromium).
Prints one JSON line: the PNG path, its size, the fraction of non-white pixels and the pixel
standard deviation; exits 1 when Chromium fails or the page looks blank (almost all one colour).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["check_png", "find_chromium", "screenshot"]

BLANK_NONWHITE_FRACTION = 0.02
"""A page with fewer non-white pixels than this is called blank."""


def find_chromium(explicit: str | None = None) -> str | None:
    """The Chromium binary: ``explicit``, else chromium / chromium-browser / google-chrome on PATH."""
    if explicit:
        return explicit
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def screenshot(
    html_path: Path,
    png_path: Path,
    *,
    width: int = 1280,
    height: int = 2000,
    chromium: str | None = None,
    timeout_s: float = 120.0,
) -> Path:
    """Render ``html_path`` in headless Chromium into ``png_path`` (width x height pixels)."""
    binary = find_chromium(chromium)
    if binary is None:
        raise FileNotFoundError("chromium not found (Debian: apt-get install -y chromium)")
    png_path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="quadnav-chromium-") as profile:
        cmd = [
            binary,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            f"--user-data-dir={profile}",
            f"--screenshot={png_path.resolve()}",
            f"--window-size={width},{height}",
            html_path.resolve().as_uri(),
        ]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    if proc.returncode != 0 or not png_path.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"chromium failed (exit {proc.returncode}): {' | '.join(tail)}")
    return png_path


def check_png(png_path: Path) -> dict[str, float]:
    """Pixel statistics of a screenshot: non-white fraction and standard deviation (0-255)."""
    import matplotlib.image as mpimg

    img = mpimg.imread(png_path)[..., :3]  # float in [0, 1]
    nonwhite = float(np.mean(np.any(img < 0.94, axis=-1)))
    return {
        "width": int(img.shape[1]),
        "height": int(img.shape[0]),
        "nonwhite_fraction": nonwhite,
        "pixel_std": float(img.std() * 255.0),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("html", nargs="?", help="report to screenshot")
    p.add_argument("png", nargs="?", help="output PNG")
    p.add_argument("--demo", metavar="OUT_DIR", help="write a synthetic flight, its report and the PNG here")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=2000)
    p.add_argument("--chromium", help="Chromium binary (default: found on PATH)")
    args = p.parse_args(argv)
    if args.demo:
        from quadnav_onboard.record.synthetic import write_synthetic_flight
        from quadnav_onboard.review.cli import main as review

        out = Path(args.demo)
        out.mkdir(parents=True, exist_ok=True)
        write_synthetic_flight(out / "demo.mcap")
        if review([str(out / "demo.mcap"), "--html", str(out / "demo.html"), "-q"]) != 0:
            return 1
        html_path, png_path = out / "demo.html", out / "demo.png"
    elif args.html and args.png:
        html_path, png_path = Path(args.html), Path(args.png)
    else:
        p.error("give REPORT.html OUT.png, or --demo OUT_DIR")
    try:
        screenshot(html_path, png_path, width=args.width, height=args.height, chromium=args.chromium)
    except (OSError, RuntimeError, subprocess.TimeoutExpired) as exc:
        print(f"screenshot_report: {exc}", file=sys.stderr)
        return 1
    stats = check_png(png_path)
    blank = stats["nonwhite_fraction"] < BLANK_NONWHITE_FRACTION
    print(json.dumps({"png": str(png_path), **stats, "blank": blank}))
    return 1 if blank else 0


if __name__ == "__main__":
    sys.exit(main())
