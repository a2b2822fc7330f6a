"""The render benchmark runs and reports its figures (a smoke test: no speed is asserted here)."""

from __future__ import annotations

import json

from sim_harness.cmd_bench import run_render


def test_run_render_reports_figures_targets_and_machine() -> None:
    """run_render returns JSON-ready figures for both paths, the targets and the machine."""
    r = run_render(seconds=0.05, batch=64)
    json.dumps(r)
    assert r["world"] == "env10-forest" and r["n_obstacles"] >= 14 and r["batch_poses"] > 32
    assert r["network_inputs_32x32_frames_per_s"]["supersample_2"]["median"] > 0
    assert set(r["full_frame_ms"]) == {"848x480", "424x240", "848x480_noisy"}
    assert r["cpu_count"] >= 1 and r["target_frames_per_s_32"] == 10_000
    assert isinstance(r["meets_target_32"], bool) and "numba" in r["uses"]
