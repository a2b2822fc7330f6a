"""Motion capture through the motioncapture library, and the y-up -> world frame transform.

QUADNAV_MOCAP_HOST=192.168.1.100, optional QUADNAV_MOCAP_TYPE (default optitrack) and
QUADNAV_MOCAP_BODY (default quad). Put the vehicle on the floor, nose along the room's +x.
"""

from __future__ import annotations

import os
import time

import numpy as np
from conftest import require_env

# OptiTrack (y-up, Motive default) -> quadnav world (x forward, y left, z up); see docs/hardware.md.
R_WORLD_FROM_OPTITRACK = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def test_rigid_body_streams_at_rate_and_sits_on_the_floor() -> None:
    """The rigid body is seen in >= 95 % of frames at >= 100 Hz and, in the world frame, z ~ 0."""
    import motioncapture

    host = require_env("QUADNAV_MOCAP_HOST", "motion capture server")
    kind = os.environ.get("QUADNAV_MOCAP_TYPE", "optitrack")
    body = os.environ.get("QUADNAV_MOCAP_BODY", "quad")
    mc = motioncapture.connect(kind, {"hostname": host})
    seen, positions, t0 = 0, [], time.monotonic()
    for _ in range(200):
        mc.waitForNextFrame()
        rb = mc.rigidBodies.get(body)
        if rb is not None:
            seen += 1
            positions.append(np.asarray(rb.position, dtype=np.float64))
    rate_hz = 200 / (time.monotonic() - t0)
    print(f"mocap {kind}@{host}: {rate_hz:.0f} Hz, body '{body}' in {seen}/200 frames")
    assert rate_hz >= 100.0
    assert seen >= 190, f"rigid body '{body}' missing (names: {sorted(mc.rigidBodies)})"
    pos = np.median(np.stack(positions), axis=0)
    if kind == "optitrack":
        pos = R_WORLD_FROM_OPTITRACK @ pos
    assert abs(pos[2]) < 0.3, f"world z {pos[2]:.2f} m: up axis wrong, or ground plane not set?"
    assert np.ptp(np.stack(positions), axis=0).max() < 0.005, "a still body jitters > 5 mm"
