"""Random box layouts of a lab's room, and DAgger flying them under the lab's flight config."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from quadnav_onboard.config import ConfigError
from quadnav_onboard.daemon.config import load_flight_config
from sim_harness.cli import main
from sim_harness.collision import clearance_m
from sim_harness.lab_layouts import LayoutRanges, lab_layouts, random_layout, route_admits
from sim_harness.rl.config import TrainConfig, load_train_config
from sim_harness.rl.evaluate import NoisyDepthEnv, flight_setup_for
from sim_harness.rl.lab_task import lab_setup, lab_task
from sim_harness.rl.train import env_config_for, train
from sim_harness.world import WorldError, load_world, resolve_world_arg

REPO = Path(__file__).resolve().parents[1]
FLIGHT = str(REPO / "config" / "flight.yaml")


@pytest.fixture(scope="module")
def lab():
    """The paper's lab room under config/flight.yaml, as the lab recipe sets it up."""
    cfg = TrainConfig(shield=True, lab_world="lab01-free", lab_flight_config=FLIGHT)
    return lab_setup(cfg, env_config_for(cfg))


def _admits(lab):
    env_cfg, limits = lab.config, lab.limits
    return route_admits(lambda _w: env_cfg.shield, env_cfg.primitives.build(), env_cfg.goal_radius_m,
                        env_cfg.max_steps, (limits.altitude_floor_m, limits.altitude_ceiling_m),
                        env_cfg.reward.max_deviation_m)


def test_the_lab_setup_is_the_flight_config_in_the_room_with_the_room_known_to_the_filter(lab):
    flight = load_flight_config(FLIGHT)
    cfg = lab.config
    assert cfg.primitives.scale_m == 0.5 and cfg.max_steps == flight.mission.max_steps
    assert cfg.goal_radius_m == flight.mission.goal_radius_m and cfg.random_start_prob == 0.0
    assert cfg.reward.max_deviation_m == flight.safety.max_deviation_m
    assert cfg.start_jitter_m == flight.mission.start_tolerance_m
    sh = cfg.shield
    assert sh.enabled and sh.band_half_width_m == flight.safety.max_deviation_m
    # the room's faces less (clearance - fence margin), intersected with the geofence
    (rlo, rhi), inset = lab.room.room_box_m(), sh.clearance_m - sh.fence_margin_m
    fence = flight.safety
    np.testing.assert_allclose(sh.fence_min_m, np.maximum(np.add(rlo, inset), fence.geofence_min_m))
    np.testing.assert_allclose(sh.fence_max_m, np.minimum(np.subtract(rhi, inset), fence.geofence_max_m))
    np.testing.assert_allclose(lab.room.path.goal_m, flight.mission.waypoints_m[-1])


def test_layouts_are_reproducible_keep_the_room_and_path_and_each_leaves_a_route(lab):
    admits = _admits(lab)
    a = lab_layouts(lab.room, 12, seed=3, admits=admits)
    b = lab_layouts(lab.room, 12, seed=3, admits=admits)
    c = lab_layouts(lab.room, 12, seed=4, admits=admits)
    boxes = lambda ws: [[(o.center_m, o.size_m, o.yaw_deg) for o in w.obstacles] for w in ws]  # noqa: E731
    assert boxes(a) == boxes(b) and boxes(a) != boxes(c)
    assert {len(w.obstacles) for w in a} <= {0, 1, 2} and max(len(w.obstacles) for w in a + c) == 2
    for w in a:
        assert w.room_xy_m == lab.room.room_xy_m and w.ceiling_z_m == lab.room.ceiling_z_m
        np.testing.assert_array_equal(w.path.waypoints_m, lab.room.path.waypoints_m)
        assert admits(w)
        for o in w.obstacles:  # standing on the floor, within the ranges drawn from
            assert o.center_m[2] - o.size_m[2] / 2 == pytest.approx(0.0)
            assert 0.3 <= o.size_m[0] <= 0.6 and 0.4 <= o.size_m[1] <= 1.2
        ends = np.stack([w.path.start_m, w.path.goal_m])
        assert (clearance_m(w, ends) >= 0.3).all()


def test_the_route_test_refuses_the_closed_lab_and_admits_the_others(lab):
    admits = _admits(lab)
    flown = lambda name: flight_setup_for(  # noqa: E731
        lab.config, load_flight_config(FLIGHT), [load_world(resolve_world_arg(name))])[1][0]
    assert admits(flown("lab03")) and admits(flown("lab01")) and admits(flown("lab02"))
    assert not admits(flown("lab04"))


def test_layouts_give_up_with_a_clear_error_when_no_draw_is_admitted(lab):
    with pytest.raises(ValueError, match="only 0 of 3 layouts with a route in 10 draws"):
        lab_layouts(lab.room, 3, seed=0, admits=lambda _w: False, max_tries=10)
    # a box over the path's start cannot be drawn into a world: parse_world refuses it
    ranges = LayoutRanges(boxes=(0.0, 1.0, 0.0), s_margin_m=0.0, c_m=(0.0, 0.0))
    rng = np.random.default_rng(0)
    refused = 0
    for _ in range(30):
        try:
            random_layout(lab.room, rng, ranges)
        except WorldError:
            refused += 1
    assert refused > 0


def test_the_lab_task_flies_the_layouts_with_depth_noise_and_a_teacher_within_the_flight_limits(lab):
    cfg = TrainConfig(shield=True, lab_world="lab01-free", lab_flight_config=FLIGHT, lab_layouts=4,
                      dagger_iterations=1)
    task = lab_task(cfg, lab)
    assert len(task.worlds) == 4 and task.config is lab.config
    teacher_cfg = task.teacher.config  # type: ignore[attr-defined]
    assert teacher_cfg.goal_radius_m == lab.config.goal_radius_m
    assert teacher_cfg.max_deviation_m < lab.config.reward.max_deviation_m
    env = task.make_env(list(task.worlds), 2, seed=0, config=task.config)
    assert isinstance(env, NoisyDepthEnv)
    assert teacher_cfg.respect_filter is False
    strict = lab_task(dataclasses.replace(cfg, teacher_respect_filter=True), lab)
    assert strict.teacher.config.respect_filter is True  # type: ignore[attr-defined]
    assert task.noise is None  # unset: DAgger's noise, as in the paper worlds
    assert lab_task(dataclasses.replace(cfg, lab_dagger_noise=0.0), lab).noise == 0.0


def test_lab_keys_are_checked_before_a_run_starts(tmp_path):
    with pytest.raises(ConfigError, match=r"key 'lab_layouts'.*set lab_world, lab_flight_config"):
        load_train_config({"lab_layouts": 5, "dagger_iterations": 1}, "r.yaml")
    with pytest.raises(ConfigError, match="key 'imitation_scales': bad value \\[\\]"):
        load_train_config({"imitation_scales": [], "dagger_iterations": 1}, "r.yaml")
    cfg = TrainConfig(shield=True, lab_world="no-such-room.yaml", lab_flight_config=FLIGHT, lab_layouts=2,
                      dagger_iterations=1, imitation_only=True, out_dir=str(tmp_path))
    with pytest.raises((ConfigError, WorldError), match="no-such-room"):
        train(cfg, progress=False)
    assert not any(tmp_path.iterdir())  # no run directory for a config that cannot run


def test_dagger_in_the_lab_labels_the_layouts_states_and_saves_a_model(tmp_path):
    cfg = TrainConfig(
        name="lab", shield=True, lab_world="lab01-free", lab_flight_config=FLIGHT, lab_layouts=3,
        imitation_scales=(), dagger_iterations=2, dagger_episodes=3, dagger_filtered_share=0.5,
        imitation_only=True, imitation_epochs=1.0, n_envs=4, batch_size=32, double_dqn=True, dueling=True,
        depth_history=3, position_history=3, out_dir=str(tmp_path), dagger_noise=0.5, lab_dagger_noise=0.0,
    )
    result = train(cfg, progress=False)
    records = json.loads((result.run_dir / "dagger.json").read_text())
    assert [r["iteration"] for r in records] == [0, 1]
    assert all(r["scale_m"] == 0.5 and r["worlds"] == 3 for r in records)
    assert all(r["noise"] == 0.0 for r in records)  # the lab's own noise, not DAgger's 0.5
    assert sum(records[0]["outcomes"].values()) == 3  # the episodes asked for, each one labelled
    assert records[1]["dataset"] > records[0]["dataset"] > 0
    assert result.model_path.exists()


def test_eval_flies_random_layouts_of_a_room_under_a_flight_config(tmp_path, capsys):
    out = tmp_path / "lay.json"
    rc = main(["eval", "--flight-config", FLIGHT, "--world", "lab01", "--layouts", "2", "--trials", "1",
               "--no-progress", "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["layouts"] == 2 and data["layout_seed"] == 4242
    assert [r["world"] for r in data["rows"]] == ["lab01-free-layout000", "lab01-free-layout001"]
    assert main(["eval", "--world", "lab01", "--layouts", "2"]) == 2
    assert "--layouts N needs --flight-config" in capsys.readouterr().err


def test_the_lab_recipe_loads_and_flies_only_the_lab():
    from quadnav_onboard.config import load_yaml

    cfg = load_train_config(load_yaml(REPO / "recipes" / "lab.yaml"), "recipes/lab.yaml")
    assert cfg.lab_layouts > 0 and cfg.imitation_scales == () and cfg.imitation_teacher == "privileged"
    assert (REPO / cfg.init_model).exists() and (REPO / cfg.lab_flight_config).exists()
    assert resolve_world_arg(cfg.lab_world).name == "lab01-free.yaml"
