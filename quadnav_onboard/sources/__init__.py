"""Sensor and vehicle interfaces of the daemon, each with hardware and sim implementations."""

from quadnav_onboard.sources.base import DepthFrame, DepthSource, OdometrySample, OdometrySource

__all__ = ["DepthFrame", "DepthSource", "OdometrySample", "OdometrySource"]
