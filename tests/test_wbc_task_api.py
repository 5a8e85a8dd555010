"""A new whole-body-controller task written against the documented API: two pure functions.

``FrameHeightTask`` below is the whole task (docstring to ``compute_drift``, under 30 lines): it
holds the height of a model frame. The tests check its Jacobian and drift against finite
differences, and that a balance controller given it lowers the G1's pelvis in MuJoCo.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from giwbc.control import ComTask, FramePoseTask, Kinodynamics, PostureTask, WbcTask, WholeBodyController, make_balance_controller
from giwbc.control.kinodynamics import LWA
from giwbc.robot import MujocoRobot


class FrameHeightTask(WbcTask):
    """World height (z) of a model frame: one row."""

    def __init__(self, frame: str, height: float, *, weight: float = 1.0, kp: float = 100.0) -> None:
        super().__init__(f"{frame}_height", 1, weight=weight, kp=kp)
        self.frame, self.height = frame, float(height)

    def bind(self, kin: Kinodynamics) -> None:
        super().bind(kin)
        self.frame_id = kin.frame_id(self.frame)

    def compute_error(self, kin: Kinodynamics) -> np.ndarray:
        return np.array([self.height - kin.frame_placement(self.frame_id).translation[2]])

    def compute_jacobian(self, kin: Kinodynamics) -> np.ndarray:
        return kin.frame_jacobian(self.frame_id, LWA)[2:3]

    def compute_drift(self, kin: Kinodynamics) -> np.ndarray:
        return kin.frame_drift(self.frame_id, LWA)[2:3]


def test_the_pure_functions_match_finite_differences(g1, rng) -> None:
    model = g1.build_pinocchio()
    kin = Kinodynamics(model)
    task = FrameHeightTask("pelvis", 0.7)
    task.bind(kin)
    q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
    q[3:7] = pin.Quaternion(pin.exp3(rng.normal(0, 0.3, 3))).coeffs()
    v, a = rng.normal(0, 1, model.nv), rng.normal(0, 1, model.nv)
    kin.update(q, v)
    task.compute(kin)  # through the default write()
    jacobian, drift, error = task.jacobian.copy(), task.drift.copy(), task.error.copy()
    height = lambda qq: (kin.update(qq, v), kin.frame_placement(task.frame_id).translation[2])[1]  # noqa: E731
    eps = 1e-6
    numeric = np.array([(height(pin.integrate(model, q, eps * e)) - height(pin.integrate(model, q, -eps * e))) / (2 * eps)
                        for e in np.eye(model.nv)])
    np.testing.assert_allclose(jacobian[0], numeric, atol=1e-6)
    kin.update(q, v)
    assert error[0] == pytest.approx(0.7 - kin.frame_placement(task.frame_id).translation[2], abs=1e-12)
    rates = []
    for sign in (1.0, -1.0):  # d/dt (J v) = J a + J̇ v along q ⊕ v t, v + a t
        kin.update(pin.integrate(model, q, sign * v * 1e-6), v + sign * a * 1e-6)
        rates.append(task.compute_jacobian(kin) @ kin.v)
    np.testing.assert_allclose(jacobian @ a + drift, (rates[0] - rates[1]) / 2e-6, atol=2e-5)


def test_a_task_without_error_or_write_says_so(g1) -> None:
    class Incomplete(WbcTask):
        pass

    kin = Kinodynamics(g1.build_pinocchio())
    task = Incomplete("incomplete", 1)
    task.bind(kin)
    with pytest.raises(NotImplementedError, match="Incomplete implements neither"):
        task.compute(kin)


@pytest.mark.slow
def test_the_new_task_lowers_the_pelvis_in_closed_loop(g1) -> None:
    """Given the height task 4 cm below the standing pelvis (weighted above the CoM task, which holds
    the CoM height), the G1 crouches by 4 cm and stays up."""
    robot = MujocoRobot(g1)
    controller = make_balance_controller(g1)
    q, v = robot.generalized_state()
    controller.reset(q)
    start = robot.base_state().position[2]
    controller.wbc.add_task(FrameHeightTask("pelvis", start - 0.04, weight=1000.0, kp=50.0))
    for _ in range(int(round(1.5 / g1.timestep))):
        controller.step(robot)
        robot.step()
    state = robot.base_state()
    assert state.position[2] == pytest.approx(start - 0.04, abs=0.01)
    assert state.rotation[2, 2] > np.cos(np.radians(5.0))  # upright


class _PelvisHeight(FrameHeightTask):
    """A custom task that leaves every gain at ``WbcTask``'s defaults."""

    def __init__(self) -> None:
        WbcTask.__init__(self, "pelvis_height", 1)
        self.frame, self.height = "pelvis", 2.0


def test_a_custom_task_without_gains_asks_for_no_feedback(g1, rng) -> None:
    """``WbcTask``'s default gains are zero: a custom task built without gains asks for no
    acceleration, however far from its target (1 m and more here) and however fast it moves."""
    model = g1.build_pinocchio()
    kin = Kinodynamics(model)
    task = _PelvisHeight()
    task.bind(kin)
    np.testing.assert_array_equal(task.kp, 0.0)
    np.testing.assert_array_equal(task.kd, 0.0)
    v = rng.uniform(-1.0, 1.0, model.nv)
    kin.update(g1.default_configuration(), v)
    task.compute(kin)
    assert task.error[0] > 1.0 and abs(task.jacobian @ v)[0] > 1e-3
    np.testing.assert_array_equal(task.desired_acceleration(), 0.0)



def _standing_tasks(g1, q0: np.ndarray) -> list[WbcTask]:
    """CoM, pelvis orientation and posture tasks, every reference given (none held from a tick)."""
    com = ComTask(weight=10.0, kp=50.0)
    com.set_reference(np.array([0.0, 0.0, 0.7]))
    pelvis = FramePoseTask(g1.base_link, "pelvis", mask=[False, False, False, True, True, True], weight=5.0, kp=80.0)
    pelvis.set_reference(pin.SE3.Identity())
    posture = PostureTask(dim=len(q0) - 7, weight=0.1, kp=20.0, reference=q0[7:])
    return [com, pelvis, posture]


def test_switching_task_sets_builds_the_same_qp_as_a_fresh_controller(g1, rng) -> None:
    """A walker swaps a swing foot's pose task in and out: the controller reuses each task set's
    stack. Every tick's QP (Hessian, gradient) must be bit for bit the one a new controller with
    the same tasks builds — also after a task's weight changed while it was out."""
    model = g1.build_pinocchio()
    q0 = g1.default_configuration()
    switching = WholeBodyController(model)
    for task in _standing_tasks(g1, q0):
        switching.add_task(task)
    swing = FramePoseTask("left_ankle_roll_link", "swing", weight=30.0, kp=200.0)
    target = pin.SE3(np.eye(3), np.array([0.1, 0.12, 0.1]))
    present = 0
    for tick in range(10):
        q = pin.integrate(model, q0, rng.normal(0.0, 0.02, model.nv))
        v = rng.normal(0.0, 0.3, model.nv)
        with_swing = tick % 3 != 0
        if with_swing and not any(t is swing for t in switching.tasks):
            swing.set_weight(30.0 + tick)  # changed while out of the QP
            switching.add_task(swing)
        elif not with_swing and any(t is swing for t in switching.tasks):
            switching.remove_task("swing")
        present += with_swing
        velocity, acceleration = rng.normal(0.0, 0.1, 6), rng.normal(0.0, 1.0, 6)
        swing.set_reference(target, velocity, acceleration)
        fresh = WholeBodyController(model)
        for task in _standing_tasks(g1, q0):
            fresh.add_task(task)
        if with_swing:
            twin = fresh.add_task(FramePoseTask("left_ankle_roll_link", "swing", weight=swing.weight, kp=200.0))
            twin.set_reference(target, velocity, acceleration)
        a, b = switching.build(q, v, 0.002 * tick).copy(), fresh.build(q, v, 0.002 * tick)
        np.testing.assert_array_equal(a.H, b.H)
        np.testing.assert_array_equal(a.g, b.g)
    assert 0 < present < 10


def test_more_task_sets_than_the_controller_keeps_build_the_same_qp_as_a_fresh_controller(g1, rng) -> None:
    """The controller keeps the stacks of a few task sets only: laying out more sets than it keeps
    (the oldest stack dropped), then one whose stack was dropped, still builds every tick's QP bit
    for bit as a new controller with the same tasks does."""
    model = g1.build_pinocchio()
    q0 = g1.default_configuration()
    controller = WholeBodyController(model)
    for task in _standing_tasks(g1, q0):
        controller.add_task(task)
    targets = [pin.SE3(np.eye(3), np.array([0.1, 0.12, 0.01 * k])) for k in range(12)]
    extras = [FramePoseTask("left_ankle_roll_link", f"swing{k}", weight=30.0 + k, kp=200.0) for k in range(12)]
    for k, target in zip(range(12), targets):
        extras[k].set_reference(target)
    for tick, k in enumerate([*range(12), 0, 11]):  # twelve sets, then a dropped one and a kept one again
        if tick:
            controller.remove_task(controller.tasks[-1].name)
        controller.add_task(extras[k])
        q = pin.integrate(model, q0, rng.normal(0.0, 0.02, model.nv))
        v = rng.normal(0.0, 0.3, model.nv)
        fresh = WholeBodyController(model)
        for task in _standing_tasks(g1, q0):
            fresh.add_task(task)
        twin = fresh.add_task(FramePoseTask("left_ankle_roll_link", f"swing{k}", weight=30.0 + k, kp=200.0))
        twin.set_reference(targets[k])
        a, b = controller.build(q, v, 0.002 * tick).copy(), fresh.build(q, v, 0.002 * tick)
        np.testing.assert_array_equal(a.H, b.H)
        np.testing.assert_array_equal(a.g, b.g)


class JointAccelerationTask(WbcTask):
    """One joint's acceleration held at zero: a constant Jacobian row, written only when stale."""

    constant_jacobian = True
    zero_drift = True

    def __init__(self, joint: int, *, weight: float = 1.0) -> None:
        super().__init__("joint_acceleration", 1, weight=weight)
        self.joint = joint  # index among the joints, resolved to a velocity column by bind

    def bind(self, kin: Kinodynamics) -> None:
        super().bind(kin)
        self.column = kin.joint_v.start + self.joint

    def write(self, kin: Kinodynamics, rows: np.ndarray, error: np.ndarray, drift: np.ndarray) -> None:
        if self.rows_stale:
            rows[:] = 0.0
            rows[0, self.column] = 1.0
            drift[:] = 0.0
            self.rows_stale = False
        error[:] = 0.0


def test_a_task_bound_again_is_written_again_in_every_kept_stack(g1, rng) -> None:
    """A task moved to another controller, changed there and brought back is bound again: every
    kept stack holding it (not only the first one used after) gets its new constant rows, and the
    QP is bit for bit a new controller's."""
    model = g1.build_pinocchio()
    q0 = g1.default_configuration()
    controller, elsewhere = WholeBodyController(model), WholeBodyController(model)
    for task in _standing_tasks(g1, q0):
        controller.add_task(task)
    held = controller.add_task(JointAccelerationTask(3, weight=4.0))
    target = pin.SE3(np.eye(3), np.array([0.1, 0.12, 0.1]))
    swings = {name: FramePoseTask("left_ankle_roll_link", name, weight=30.0, kp=200.0) for name in ("x", "y")}
    for swing in swings.values():
        swing.set_reference(target)

    def tick(swing: str, tick: int) -> None:
        q = pin.integrate(model, q0, rng.normal(0.0, 0.02, model.nv))
        v = rng.normal(0.0, 0.3, model.nv)
        fresh = WholeBodyController(model)
        for task in _standing_tasks(g1, q0):
            fresh.add_task(task)
        fresh.add_task(JointAccelerationTask(held.joint, weight=4.0))
        fresh.add_task(FramePoseTask("left_ankle_roll_link", swing, weight=30.0, kp=200.0)).set_reference(target)
        a, b = controller.build(q, v, 0.002 * tick).copy(), fresh.build(q, v, 0.002 * tick)
        np.testing.assert_array_equal(a.H, b.H)
        np.testing.assert_array_equal(a.g, b.g)

    controller.add_task(swings["x"])
    tick("x", 0)  # the stack of [standing, held, x]
    controller.remove_task("x")
    controller.add_task(swings["y"])
    tick("y", 1)  # the stack of [standing, held, y]
    controller.remove_task("y")
    controller.remove_task(held.name)
    elsewhere.add_task(held)  # bound to another controller's model, then changed and brought back
    elsewhere.remove_task(held.name)
    held.joint = 5
    controller.add_task(held)
    controller.add_task(swings["y"])
    tick("y", 2)  # the kept stack of [standing, held, y]: the held task's rows were stale anyway
    controller.remove_task("y")
    controller.add_task(swings["x"])
    tick("x", 3)  # the kept stack of [standing, held, x]: its rows are written again too
