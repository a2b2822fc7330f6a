"""The culled numba ray caster equals a brute-force numpy caster (every ray against every shape).

Culling (range, screen rectangles from oriented bounding boxes or bounding spheres, nearest-first
occlusion skipping) must never change a depth within range. Checked on random worlds of every
shape, at random full attitudes (roll and pitch included), some poses close to obstacles so that
box corners fall behind the camera.
"""

from __future__ import annotations

import numpy as np

from quadnav_onboard.frames import quat_to_rotmat
from quadnav_onboard.path import RoughPath
from sim_harness.render import CameraModel, cast_depth_m
from sim_harness.world import Box, Cylinder, Geometry, Sphere, World


def _brute_force(g: Geometry, pos: np.ndarray, rot: np.ndarray, cam: CameraModel) -> np.ndarray:
    ty, tz = cam.ray_slopes()
    d_body = np.stack(np.broadcast_arrays(1.0, ty[None, :], tz[:, None]), -1).reshape(-1, 3)
    d = np.einsum("nab,rb->nra", rot, d_body)  # (N, R, 3) world directions, body-x component 1
    o = pos[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.minimum(np.where(d[..., 2] < 0, (g.floor_z_m - o[..., 2]) / d[..., 2], np.inf),
                       np.where(d[..., 2] > 0, (g.ceiling_z_m - o[..., 2]) / d[..., 2], np.inf))
        for m in range(len(g.kind)):
            ol, dl, h = (o - g.center_m[m]) @ g.rot_m[m], d @ g.rot_m[m], g.half_m[m]
            if g.kind[m] == 1:  # sphere: near root of |ol + t dl|^2 = r^2
                a, b = (dl * dl).sum(-1), (ol * dl).sum(-1)
                disc = b * b - a * ((ol * ol).sum(-1) - h[0] ** 2)
                tn = (-b - np.sqrt(np.maximum(disc, 0))) / a
                tx = np.where(disc >= 0, (-b + np.sqrt(np.maximum(disc, 0))) / a, -np.inf)
            else:  # slabs; for a cylinder, z slab and the infinite cylinder's interval
                t1, t2 = (-h - ol) / dl, (h - ol) / dl
                lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
                if g.kind[m] == 0:
                    tn, tx = lo.max(-1), hi.min(-1)
                else:
                    a = dl[..., 0] ** 2 + dl[..., 1] ** 2
                    b = ol[..., 0] * dl[..., 0] + ol[..., 1] * dl[..., 1]
                    disc = b * b - a * (ol[..., 0] ** 2 + ol[..., 1] ** 2 - h[0] ** 2)
                    sq = np.sqrt(np.maximum(disc, 0))
                    tn = np.maximum(lo[..., 2], (-b - sq) / a)
                    tx = np.where(disc >= 0, np.minimum(hi[..., 2], (-b + sq) / a), -np.inf)
            hit = (tn <= tx) & (tx > 0)
            t = np.where(hit, np.minimum(t, np.maximum(tn, 0.0)), t)
    return t.reshape(len(pos), tz.size, ty.size)


def _random_world(rng: np.random.Generator) -> World:
    obs = []
    for _ in range(25):
        c = (rng.uniform(0, 20), rng.uniform(-5, 5), rng.uniform(0, 5))
        k = rng.integers(3)
        if k == 0:
            obs.append(Box(c, tuple(rng.uniform(0.1, 4, 3)), rng.uniform(-180, 180)))
        elif k == 1:
            obs.append(Sphere(c, rng.uniform(0.2, 2)))
        else:
            obs.append(Cylinder(c, rng.uniform(0.1, 1.5), rng.uniform(0.2, 6), "xyz"[rng.integers(3)]))
    return World("random", RoughPath.straight([0, 0, 2], [20, 0, 2]), floor_z_m=-0.5, ceiling_z_m=6.0,
                 obstacles=tuple(obs))


def test_culled_caster_equals_brute_force_within_range() -> None:
    """Within max range, every pixel's depth equals the brute-force answer to 1e-9 m."""
    rng = np.random.default_rng(11)
    cam = CameraModel(40, 30, min_range_m=0.1, max_range_m=12.0)
    for _ in range(3):
        w = _random_world(rng)
        n = 40
        pos = np.stack([rng.uniform(-2, 20, n), rng.uniform(-5, 5, n), rng.uniform(0, 5, n)], -1)
        axes = rng.normal(size=(n, 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        ang = rng.uniform(-np.pi, np.pi, n)
        q = np.concatenate([np.cos(ang / 2)[:, None], np.sin(ang / 2)[:, None] * axes], axis=1)
        rot = quat_to_rotmat(q)
        for parallel in (False, True):
            fast = cast_depth_m(w.geometry, pos, rot, cam, parallel=parallel)
            ref = _brute_force(w.geometry, pos, rot, cam)
            near = np.minimum(fast, ref) <= cam.max_range_m
            assert near.mean() > 0.3
            np.testing.assert_allclose(fast[near], ref[near], atol=1e-9, rtol=0)
