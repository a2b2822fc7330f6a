"""Odometry from PX4's own estimator over MAVSDK telemetry (when no mocap feeds the daemon).

The frame conversion (NED/FRD -> world/FLU) lives in
:meth:`quadnav_onboard.vehicle.MavsdkVehicle.odometry_samples`; this wrapper only adapts it to the
:class:`~quadnav_onboard.sources.base.OdometrySource` protocol.
"""

from __future__ import annotations

from collections.abc import AsyncIterator

from quadnav_onboard.sources.base import OdometrySample
from quadnav_onboard.vehicle import MavsdkVehicle

__all__ = ["Px4OdometrySource"]


class Px4OdometrySource:
    """Samples from the vehicle link's ODOMETRY stream (the link must be the daemon's vehicle)."""

    def __init__(self, vehicle: MavsdkVehicle) -> None:
        self.vehicle = vehicle

    async def __aenter__(self) -> Px4OdometrySource:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    def samples(self) -> AsyncIterator[OdometrySample]:
        return self.vehicle.odometry_samples()
