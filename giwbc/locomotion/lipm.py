"""Linear inverted pendulum (LIPM) and its divergent component of motion (DCM), closed forms.

With the CoM at constant height ``z₀`` above the ground, ``ω = √(g / z₀)`` and the CoP (ZMP) ``p``,
the horizontal CoM obeys ``c̈ = ω² (c − p)``. Its divergent component ``ξ = c + ċ / ω`` obeys
``ξ̇ = ω (ξ − p)`` (unstable), the CoM follows it ``ċ = ω (ξ − c)`` (stable). With the CoP held
at ``p`` the DCM diverges as ``ξ(t) = p + (ξ₀ − p) e^{ωt}``: put the CoP (the next foot) at ``ξ``
and the pendulum comes to rest there — ``ξ`` *is* the (instantaneous) capture point.

All functions take scalars or arrays of horizontal points (last axis x, y) and broadcast.
"""

from __future__ import annotations

import math

import numpy as np

GRAVITY = 9.81


def natural_frequency(com_height: float, gravity: float = GRAVITY) -> float:
    """``ω = √(g / z₀)``, s⁻¹ (G1, z₀ ≈ 0.68 m: ω ≈ 3.8 s⁻¹)."""
    if not (math.isfinite(com_height) and com_height > 0):
        raise ValueError(f"CoM height must be finite and > 0, got {com_height}")
    if not (math.isfinite(gravity) and gravity > 0):
        raise ValueError(f"gravity must be finite and > 0, got {gravity}")
    return math.sqrt(gravity / com_height)


def dcm(com: np.ndarray, com_velocity: np.ndarray, omega: float) -> np.ndarray:
    """``ξ = c + ċ / ω`` — also the instantaneous capture point."""
    return np.asarray(com, dtype=float) + np.asarray(com_velocity, dtype=float) / omega


capture_point = dcm


def dcm_at(t: float | np.ndarray, xi0: np.ndarray, cop: np.ndarray, omega: float) -> np.ndarray:
    """``ξ(t) = p + (ξ₀ − p) e^{ωt}``: the DCM ``t`` s later with the CoP held at ``cop``."""
    cop = np.asarray(cop, dtype=float)
    growth = np.exp(omega * np.asarray(t, dtype=float))
    return cop + (np.asarray(xi0, dtype=float) - cop) * (growth[..., None] if np.ndim(growth) else growth)


def dcm_before(duration: float, xi_end: np.ndarray, cop: np.ndarray, omega: float) -> np.ndarray:
    """The DCM that reaches ``xi_end`` after ``duration`` s with the CoP held at ``cop``:
    ``ξ₀ = p + (ξ_end − p) e^{−ωT}`` (the backward step of a DCM plan)."""
    cop = np.asarray(cop, dtype=float)
    return cop + (np.asarray(xi_end, dtype=float) - cop) * math.exp(-omega * duration)


def dcm_at_linear_cop(t: float, duration: float, xi0: np.ndarray, cop_start: np.ndarray, cop_end: np.ndarray, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """DCM and its rate at ``t`` with the CoP moving linearly from ``cop_start`` to ``cop_end``
    over ``duration``: ``ξ(t) = p(t) + ṗ/ω + (ξ₀ − p₀ − ṗ/ω) e^{ωt}``."""
    p0 = np.asarray(cop_start, dtype=float)
    rate = (np.asarray(cop_end, dtype=float) - p0) / duration
    p = p0 + rate * t
    offset = (np.asarray(xi0, dtype=float) - p0 - rate / omega) * math.exp(omega * t)
    xi = p + rate / omega + offset
    return xi, omega * (xi - p)


def dcm_before_linear_cop(duration: float, xi_end: np.ndarray, cop_start: np.ndarray, cop_end: np.ndarray, omega: float) -> np.ndarray:
    """Inverse of :func:`dcm_at_linear_cop` at ``t = duration``: the start DCM reaching ``xi_end``."""
    p0 = np.asarray(cop_start, dtype=float)
    p1 = np.asarray(cop_end, dtype=float)
    shift = (p1 - p0) / (duration * omega)
    return p0 + shift + (np.asarray(xi_end, dtype=float) - p1 - shift) * math.exp(-omega * duration)


def com_at(t: float, com0: np.ndarray, com_velocity0: np.ndarray, cop: np.ndarray, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """CoM position and velocity ``t`` s later with the CoP held at ``cop`` (LIPM closed form):
    ``c(t) = p + (c₀ − p) cosh ωt + ċ₀/ω sinh ωt``."""
    cop = np.asarray(cop, dtype=float)
    offset = np.asarray(com0, dtype=float) - cop
    velocity0 = np.asarray(com_velocity0, dtype=float)
    ch, sh = math.cosh(omega * t), math.sinh(omega * t)
    return cop + offset * ch + velocity0 / omega * sh, offset * omega * sh + velocity0 * ch


def cop_for_dcm_rate(xi: np.ndarray, xi_rate: np.ndarray, omega: float) -> np.ndarray:
    """The CoP that gives the DCM the rate ``ξ̇``: ``p = ξ − ξ̇ / ω``."""
    return np.asarray(xi, dtype=float) - np.asarray(xi_rate, dtype=float) / omega


def cop_start_for_dcm(xi0: np.ndarray, duration: float, xi_end: np.ndarray, cop_end: np.ndarray, omega: float) -> np.ndarray:
    """The start of a linear CoP ramp ending at ``cop_end`` after ``duration`` that takes the DCM
    from ``xi0`` to ``xi_end``: :func:`dcm_before_linear_cop` solved for the ramp's start (it is
    affine in it). Lets a re-planned reference start *at* the measured DCM."""
    a = 1.0 / (omega * duration)
    decay = math.exp(-omega * duration)
    p1 = np.asarray(cop_end, dtype=float)
    numerator = np.asarray(xi0, dtype=float) - a * p1 - decay * (np.asarray(xi_end, dtype=float) - p1 - a * p1)
    return numerator / (1.0 - a + a * decay)
