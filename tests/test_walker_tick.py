"""The walker's tick made cheaper (issue 37) walks as before: ``step(robot)`` reads the feet's normal
forces only when its contact schedule asks (the swinging foot's, late in a swing) and walks bit for
bit as when both are read before every tick; the DCM shaper's floats give its 2-vector bits."""

from __future__ import annotations

import math

import numpy as np

from giwbc.locomotion.step_adapter import DcmErrorShaper
from giwbc.locomotion.walker import Phase, WalkingController
from giwbc.robot.mujoco_robot import MujocoRobot


def test_step_reads_only_the_swinging_foot_late_in_a_swing_and_walks_as_an_eager_read(g1) -> None:
    """1.6 s of MuJoCo at 0.3 m/s, the same start twice: one walker through ``step(robot)``, one
    through ``update`` with both feet's forces read before each tick. Same torques at every tick
    (bit for bit), the walk steps, and the lazy one read no force outside single support, only the
    swinging foot's, and none in the first ``early_touchdown`` of a swing."""
    robots = [MujocoRobot(g1), MujocoRobot(g1)]
    walkers = [WalkingController(g1), WalkingController(g1)]
    for robot, walker in zip(robots, walkers):
        walker.reset(robot.generalized_state()[0])
        walker.set_command(0.3)
    lazy, eager = walkers
    links = {contact.link: side for side, contact in lazy.contacts.items()}
    reads: list[tuple[str, Phase, str, float]] = []  # (side read, phase, stance, swing progress) at the read
    read = robots[0].contact_wrench

    def counted(link: str):
        reads.append((links[link], lazy._phase, lazy._stance, lazy.phase_progress()))
        return read(link)

    robots[0].contact_wrench = counted  # type: ignore[method-assign]
    single = 0
    for _ in range(800):
        phase = lazy.phase
        before = len(reads)
        tau = lazy.step(robots[0]).tau
        q, v = robots[1].generalized_state()
        forces = {side: float(robots[1].contact_wrench(contact.link).force[2]) for side, contact in eager.contacts.items()}
        other = eager.update(q, v, robots[1].time(), forces).tau
        robots[1].set_joint_torques(other)
        np.testing.assert_array_equal(tau, other)
        if phase is not Phase.SINGLE:
            assert len(reads) == before  # standing or in double support: nothing read
        single += phase is Phase.SINGLE
        for robot in robots:
            robot.step()
    assert lazy.state.steps >= 2 and lazy.state.steps == eager.state.steps  # it walked, touch-downs detected on the forces
    assert reads and len(reads) < single  # at most one read a tick, and none early in a swing
    for side, phase, stance, progress in reads:
        assert phase is Phase.SINGLE and side != stance
        assert progress >= lazy.config.early_touchdown - 1e-9


def _shaped_with_numpy(shaper_state: dict, shaper, t: float, measured: np.ndarray, nominal: np.ndarray) -> np.ndarray:
    """:class:`~giwbc.locomotion.step_adapter.DcmErrorShaper`'s step on 2-vectors (its formulation
    before issue 37's floats), state in ``shaper_state``."""
    error = np.asarray(measured, dtype=float)[:2] - np.asarray(nominal, dtype=float)[:2]
    last = shaper_state.get("last")
    if shaper.time_constant > 0.0 and last is not None:
        last_t, previous = last
        dt = max(t - last_t, 0.0)
        error = previous + dt / (shaper.time_constant + dt) * (error - previous)
    shaper_state["last"] = (float(t), error)
    size = float(np.linalg.norm(error))
    plain = max(1.0 - shaper.deadband / size, 0.0) if size > 0.0 else 0.0
    scale = plain
    if size >= shaper.full_error:
        scale = 1.0
    elif math.isfinite(shaper.full_error):
        scale = max(size - shaper.deadband, 0.0) * shaper.full_error / ((shaper.full_error - shaper.deadband) * size) if size > 0.0 else 0.0
        if shaper.fade_delay > 0.0:
            if size <= shaper.deadband:
                shaper_state["since"] = None
            elif shaper_state.get("since") is None:
                shaper_state["since"] = float(t)
            since = shaper_state.get("since")
            lasted = 0.0 if since is None else min((float(t) - since) / shaper.fade_delay, 1.0)
            scale = plain + lasted * (scale - plain)
    return np.asarray(nominal, dtype=float)[:2] + error * scale


def test_the_dcm_shaper_on_floats_gives_its_numpy_formulations_bits() -> None:
    """Random error sequences through every kind of shaper (deadband, low-pass, fading, fade delay;
    repeated times, resets, a zero error): the float arithmetic the walker runs at every tick of a
    swing equals the 2-vector one, bit for bit."""
    rng = np.random.default_rng(37)
    for deadband, time_constant, full_error, fade_delay in [(0.0, 0.02, math.inf, 0.0), (0.03, 0.0, math.inf, 0.0), (0.02, 0.03, 0.1, 0.0),
                                                            (0.02, 0.03, 0.1, 0.1), (0.01, 0.0, 0.06, 0.05)]:
        shaper, state, t = DcmErrorShaper(deadband, time_constant, full_error, fade_delay), {}, 0.0
        for _ in range(400):
            t += float(rng.choice([0.002, 0.0, 0.004]))
            nominal = rng.normal(0.0, 0.05, 2)
            measured = nominal.copy() if rng.uniform() < 0.05 else nominal + rng.normal(0.0, 0.05, 2) * rng.choice([0.1, 1.0, 3.0])
            if rng.uniform() < 0.03:
                shaper.reset()
                state.clear()
            assert shaper(t, measured, nominal).tobytes() == _shaped_with_numpy(state, shaper, t, measured, nominal).tobytes()
