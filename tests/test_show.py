"""`quadnav-sim show`: PNGs of worlds (and of what the camera sees), and clear errors for bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from sim_harness.cli import main
from sim_harness.show import draw_world
from sim_harness.world import load_world, paper_world_path


def test_draw_world_has_views_and_with_a_pose_the_camera_panels() -> None:
    """Without a pose: top and side views with one patch per obstacle; with one: depth and input too."""
    w = load_world(paper_world_path(8))
    fig = draw_world(w)
    top, side = fig.axes
    assert len(top.patches) == len(side.patches) == len(w.obstacles)
    assert top.get_xlabel().startswith("x forward") and side.get_ylabel().startswith("z up")
    fig = draw_world(w, pose_m=np.array([44.0, 0.0, 2.0]), yaw_rad=0.0)
    titles = [ax.get_title() for ax in fig.axes]
    assert any(t.startswith("depth 424x240") for t in titles) and "network input 32x32" in titles
    depth = fig.axes[2].images[0].get_array()
    assert np.nanmin(depth) < 3.0 < np.nanmax(depth)  # corridor walls near, the corridor far


def test_cli_writes_a_png_for_a_paper_world_id(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`show env04 --pose ... -o X.png` writes a real, non-blank PNG and prints its path."""
    out = tmp_path / "env04.png"
    assert main(["show", "env04", "--pose", "5", "0", "2", "0", "-o", str(out)]) == 0
    img = imread(out)
    assert img.shape[0] > 500 and img.shape[1] > 1000 and img[..., :3].std() > 0.05
    assert str(out) in capsys.readouterr().out


def test_cli_bad_world_file_is_an_error_message_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bad world file gives exit code 2 and one line naming the file, the entry and the reason."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\npath: {waypoints: [[0,0,2],[9,0,2]]}\n"
                   "obstacles:\n - {type: cone, center: [1,1,1]}\n")
    assert main(["show", str(bad), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "obstacles[0]" in err and "unknown shape type 'cone'" in err
    assert "Traceback" not in err and not (tmp_path / "x.png").exists()
