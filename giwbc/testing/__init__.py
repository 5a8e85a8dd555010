"""Test support: closed-form dynamics models, their Pinocchio twins and pytest-friendly checks.

* ``giwbc.testing.analytic`` — hand-derived ``M``, ``C q̇``, ``g`` of a simple pendulum, a double
  pendulum, a cart-pole (matching ``robots/cartpole/cartpole.urdf``), a planar floating body and
  a planar floating body with one actuated link (x–z plane, joints about +y, gravity along −z).
* ``giwbc.testing.pinocchio_models`` — the same systems as ``pinocchio.Model`` objects.
* ``giwbc.testing.checks`` — ``assert_dynamics_match``, ``assert_computed_torque``, physical
  consistency checks and ``PinocchioDynamics``, an adapter from ``pinocchio.Model``.

Only ``analytic`` is imported eagerly (pure numpy); the others import Pinocchio.
"""

from giwbc.testing.analytic import (
    STANDARD_GRAVITY,
    AnalyticModel,
    CartPole,
    DoublePendulum,
    PlanarFloatingArm,
    PlanarFloatingBody,
    SimplePendulum,
)

__all__ = [
    "STANDARD_GRAVITY",
    "AnalyticModel",
    "CartPole",
    "DoublePendulum",
    "PlanarFloatingArm",
    "PlanarFloatingBody",
    "SimplePendulum",
]
