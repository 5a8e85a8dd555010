"""IMU profiles as randomization entries: each episode draws the turn-on errors of a named IMU class.

:func:`imu_profile_entries` turns a :data:`giwbc.robot.noise.IMU_PROFILES` profile into config
entries (gaussian turn-on gyro and accelerometer biases, mounting misalignment and orientation
output errors with the profile's standard deviations; its noise, latency, dropouts, timestamp
jitter and encoder quantization as they are), so that a randomization config covers the IMUs
people mount: ``{"imu_profile": "mems", "parameters": [...]}`` prepends them. The profile's
``orientation_output`` flag is not randomized: an IMU without one is a different robot
configuration (its estimator runs the gravity path), not an episode's draw.
"""

from __future__ import annotations

import math
from typing import Any

from giwbc.randomization.distributions import RandomizationError
from giwbc.robot.noise import IMU_PROFILES, SensorNoiseConfig

__all__ = ["imu_profile_entries"]


def imu_profile_entries(name: str) -> list[dict[str, Any]]:
    """Randomization entries drawing, per episode, the sensor errors of IMU profile ``name``."""
    if name not in IMU_PROFILES:
        raise RandomizationError(f"unknown IMU profile {name!r}; known: {sorted(IMU_PROFILES)}")
    p = SensorNoiseConfig.profile(name)
    root = 1.0 / math.sqrt(p.sample_period)

    def fixed(parameter: str, value: float) -> dict[str, Any]:
        return {"parameter": parameter, "distribution": "uniform", "low": value, "high": value, "operation": "absolute",
                "name": f"{name}:{parameter}"}

    def gaussian(parameter: str, std: float | list[float]) -> dict[str, Any]:
        size = 3 if isinstance(std, list) else 1
        return {"parameter": parameter, "distribution": "gaussian", "mean": [0.0] * size if size > 1 else 0.0, "std": std,
                "operation": "absolute", "name": f"{name}:{parameter}"}

    return [
        gaussian("gyro_bias", [p.gyro_bias] * 3),
        gaussian("accelerometer_bias", [p.accel_bias] * 3),
        fixed("gyro_noise", p.gyro_noise_density * root),
        fixed("accelerometer_noise", p.accel_noise_density * root),
        fixed("imu_orientation_noise", p.orientation_noise if p.orientation_output else 0.0),
        gaussian("imu_mounting", [p.mounting_misalignment] * 3),
        gaussian("imu_orientation_bias", [p.orientation_bias, p.orientation_bias, 0.0]),
        gaussian("imu_heading_drift", p.heading_drift),
        fixed("imu_dropout", p.imu_dropout),
        fixed("imu_timestamp_jitter", p.sample_jitter),
        fixed("encoder_resolution", p.encoder_resolution),
        fixed("imu_latency", float(p.imu_latency)),
    ]
