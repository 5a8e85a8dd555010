"""Shared fixtures: robot descriptions and models are built once per session (they take ~1 s)."""

from __future__ import annotations

import giwbc  # noqa: F401  (first: it pins the floating-point kernels before numpy loads, giwbc.numerics)
import numpy as np
import pytest

from giwbc.robot import RobotDescription, load


@pytest.fixture(scope="session")
def g1() -> RobotDescription:
    return load("g1")


@pytest.fixture(scope="session")
def cartpole() -> RobotDescription:
    return load("cartpole")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261122)
