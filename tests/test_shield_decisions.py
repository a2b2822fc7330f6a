"""The depth safety filter's flight-time rules: the known deviation band and the memory of places
visited before."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadnav_onboard.path import RoughPath
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
from quadnav_onboard.shield import PointMemory, ShieldConfig, band_clearance, shield_verdict

PRIMS = PrimitiveSet()
ALONG_X = ((0.0, 0.0, 1.5), (10.0, 0.0, 1.5))


def _blind_verdict(cfg: ShieldConfig, pos: np.ndarray) -> tuple:
    """The verdict at ``pos`` (1, 3), standing still, heading +x, after a view that saw nothing."""
    mem = PointMemory(1, cfg)
    mem.add([0], np.ones((1, 32, 32), np.float32), pos, np.zeros(1))
    still = (pos, np.zeros((1, 3)), np.zeros(1), pos, np.zeros((1, 3)))
    return shield_verdict(PRIMS, mem.points, mem.depth_m, mem.pose, *still, cfg)


def test_band_clearance_is_the_room_left_inside_the_band_round_a_polyline():
    """Samples 0.5 m and 1.2 m from a path with a corner (band 1 m): 0.5 m left, 0.2 m outside;
    the nearest segment counts, and a primitive's worst sample is its clearance."""
    corner = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 2.0, 0.0]])
    samples = np.array([[[[1.0, 0.5, 0.0], [2.5, 1.0, 0.0]], [[1.0, 0.5, 0.0], [1.0, -1.2, 0.0]]]])
    got = band_clearance(samples, RoughPath(corner), 1.0)
    assert got.shape == (1, 2)
    np.testing.assert_allclose(got[0], [0.5, -0.2])


def test_a_primitive_leaving_the_deviation_band_is_vetoed_though_no_view_saw_anything():
    """0.6 m left of a straight path with a 1.5 m band: every primitive that steps 1 m further
    left would end past the band less its margin and is vetoed; flying on along the path, or back
    towards it, stays allowed. Without the band the blind view allows all."""
    cfg = ShieldConfig(enabled=True).with_band(ALONG_X, 1.5)
    pos = np.array([[0.0, 0.6, 1.5]])
    allowed, clearance = _blind_verdict(cfg, pos)
    for a, (f, lat, v) in enumerate(DEFAULT_DIRECTIONS):
        if lat == 1:
            assert not allowed[0, a] and clearance[0, a] < cfg.clearance_m, (f, lat, v)
    for d in ((1, 0, 0), (0, 0, 0), (1, -1, 0), (0, -1, 0)):
        assert allowed[0, DEFAULT_DIRECTIONS.index(d)], d
    blind, _ = _blind_verdict(ShieldConfig(enabled=True), pos)
    assert blind.all()


def test_with_band_sets_the_path_and_half_width_and_none_leaves_the_filter_as_it_is():
    cfg = ShieldConfig(enabled=True)
    banded = cfg.with_band(np.asarray(ALONG_X), 1.5)
    assert banded.band_waypoints_m == ALONG_X and banded.band_half_width_m == 1.5
    assert cfg.with_band(None, None) is cfg and cfg.with_band(ALONG_X, None) is cfg


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"band_waypoints_m": ALONG_X}, "both"),
        ({"band_half_width_m": 1.0}, "both"),
        ({"band_waypoints_m": ALONG_X[:1], "band_half_width_m": 1.0}, ">= 2 points"),
        ({"band_waypoints_m": (ALONG_X[0], ALONG_X[0], ALONG_X[1]), "band_half_width_m": 1.0}, "distinct"),
        ({"band_waypoints_m": ALONG_X, "band_half_width_m": 0.1, "band_margin_m": 0.2}, "band_margin_m"),
    ],
)
def test_a_bad_band_is_refused(kw: dict, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        ShieldConfig(enabled=True, **kw)


def test_a_band_in_a_config_file_is_range_checked():
    from quadnav_onboard.config import ConfigError, parse_config

    with pytest.raises(ConfigError, match="band_waypoints_m"):
        bad = [[0, 0, 1], [1, 1, math.nan]]
        parse_config(ShieldConfig, {"band_waypoints_m": bad, "band_half_width_m": 1.5}, source="x")
    with pytest.raises(ConfigError, match="band_half_width_m"):
        parse_config(ShieldConfig, {"band_waypoints_m": [[0, 0, 1], [1, 1, 1]], "band_half_width_m": 0},
                     source="x")
    ok = parse_config(ShieldConfig, {"band_waypoints_m": [[0, 0, 1], [1, 1, 1]], "band_half_width_m": 1.5},
                      source="x")
    assert ok.band_waypoints_m == ((0.0, 0.0, 1.0), (1.0, 1.0, 1.0))


def _wall(distance_m: float, cfg: ShieldConfig) -> np.ndarray:
    return np.full((1, 32, 32), distance_m / cfg.max_range_m, dtype=np.float32)


def _remembered_x(mem: PointMemory) -> set[float]:
    return set(np.unique(np.round(mem.points[0, :, 0], 3)[np.isfinite(mem.points[0, :, 0])]).tolist())


def test_going_back_and_forth_between_two_places_does_not_forget_what_was_seen_before():
    """Three views: one of a wall 5 m ahead from the origin, then 0.6 m climbs and descents 1 m on
    (each farther than min_travel_m from the last view, so the newest-only rule would push the
    first view out on the second one). Each return to a place replaces that place's view, so the
    first view stays; moving on to new places still pushes the oldest out."""
    cfg = ShieldConfig(enabled=True, memory_steps=3, min_travel_m=0.3, shadow_m=0.0)
    mem = PointMemory(1, cfg)
    mem.add([0], _wall(5.0, cfg), np.zeros((1, 3)), np.zeros(1))  # sees x = 5
    for _ in range(4):
        for z in (0.0, 0.6):
            mem.add([0], _wall(2.0, cfg), np.array([[1.0, 0.0, z]]), np.zeros(1))  # sees x = 3
    assert _remembered_x(mem) == {3.0, 5.0}
    for x in (2.0, 2.5):  # new places (seeing x = 4, 4.5): the oldest, the origin's view, goes first
        mem.add([0], _wall(2.0, cfg), np.array([[x, 0.0, 0.0]]), np.zeros(1))
    assert 5.0 not in _remembered_x(mem)
