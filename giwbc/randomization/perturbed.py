"""Robot-level randomization: a Robot wrapper that any simulated robot (MuJoCo or PyBullet) runs through.

:class:`PerturbedRobot` adds what a physics model does not hold: actuator latency (commands reach
the engine ``actuator_latency`` physics steps late), PD gain scales (on impedance commands),
sensor noise and bias (joint encoders, gyro, accelerometer, IMU orientation), IMU latency, and a
push schedule. It is a ``SimulatedRobot`` itself (``step``, ``reset``, ``set_external_wrench``), so a
runtime steps it exactly as it steps the engine robot; ``step(n)`` splits at the physics steps
where a delayed command, a push start or end falls due (and steps one by one while the IMU is
delayed, to record its history). Noise is drawn from a generator seeded by the episode sample, once
per physics step: reading twice in the same step gives the same value. Base state, link poses and
contact wrenches pass through untouched (ground truth, for rewards and estimators), and so do the
engine's raw ``sensor(name)`` channels.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from giwbc.randomization.sampling import Push, Sample
from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, ImuReading, Robot


def _rotation_quaternion(rotation_vector: np.ndarray) -> np.ndarray:
    """``(x, y, z, w)`` of a rotation vector (axis * angle)."""
    angle = float(np.linalg.norm(rotation_vector))
    if angle < 1e-12:
        return np.array([*(0.5 * rotation_vector), 1.0]) / np.sqrt(1 + 0.25 * angle**2)
    axis = rotation_vector / angle
    return np.array([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


class PerturbedRobot(Robot):
    """Wraps a simulated robot; :meth:`set_perturbations` installs one episode's samples."""

    def __init__(self, robot: Robot) -> None:
        for method in ("step", "reset", "set_external_wrench"):
            if not callable(getattr(robot, method, None)):
                raise TypeError(f"{type(robot).__name__} is not a simulated robot: it has no {method}()")
        self.inner = robot
        n = robot.dofs
        self.latency = 0
        self.kp_scale, self.kd_scale = np.ones(n), np.ones(n)
        self.position_noise, self.position_bias, self.velocity_noise = np.zeros(n), np.zeros(n), np.zeros(n)
        self.gyro_noise, self.accelerometer_noise, self.orientation_noise = 0.0, 0.0, 0.0
        self.gyro_bias, self.accelerometer_bias = np.zeros(3), np.zeros(3)
        self.imu_latency = 0
        self.pushes: tuple[Push, ...] = ()
        self._rng = np.random.default_rng(0)
        self._tick = 0
        self._queue: deque[tuple[int, str, Any]] = deque()
        self._events: list[tuple[int, str, np.ndarray]] = []  # (tick, link, force): push starts and ends
        self._event_index = 0
        self._user_wrenches: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._push_force: dict[str, np.ndarray] = {}
        self._imu_history: deque[ImuReading] = deque(maxlen=1)
        self._noise_tick = -1
        self._noise: dict[str, np.ndarray] = {}

    def __getattr__(self, name: str) -> Any:
        """Everything else (``model``, ``data``, ``description``, ``sensor``, ``client``...) is the engine's."""
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    # --- configuration --------------------------------------------------------------------------
    def set_perturbations(self, physics: Sample | None, episode: Sample | None) -> None:
        """Install the robot-level parts of a physics sample and of an episode sample (``None``: nominal)."""
        n = self.dofs
        if physics is not None:
            self.latency = int(physics.scalar("actuator_latency"))
            self.kp_scale, self.kd_scale = physics["kp_scale"].copy(), physics["kd_scale"].copy()
        else:
            self.latency, self.kp_scale, self.kd_scale = 0, np.ones(n), np.ones(n)
        if episode is not None:
            self.position_noise = episode["joint_position_noise"].copy()
            self.position_bias = episode["joint_position_bias"].copy()
            self.velocity_noise = episode["joint_velocity_noise"].copy()
            self.gyro_noise, self.gyro_bias = episode.scalar("gyro_noise"), episode["gyro_bias"].copy()
            self.accelerometer_noise = episode.scalar("accelerometer_noise")
            self.accelerometer_bias = episode["accelerometer_bias"].copy()
            self.orientation_noise = episode.scalar("imu_orientation_noise")
            self.imu_latency = int(episode.scalar("imu_latency"))
            self.pushes = episode.pushes
            self._rng = np.random.default_rng(episode.noise_seed)
        else:
            self.position_noise, self.position_bias, self.velocity_noise = np.zeros(n), np.zeros(n), np.zeros(n)
            self.gyro_noise = self.accelerometer_noise = self.orientation_noise = 0.0
            self.gyro_bias, self.accelerometer_bias = np.zeros(3), np.zeros(3)
            self.imu_latency, self.pushes = 0, ()
        self._schedule_pushes()
        self._start_imu_history()

    def _start_imu_history(self) -> None:
        """Readings of the last ``imu_latency + 1`` physics steps (only kept while the IMU is delayed)."""
        self._imu_history = deque([self.inner.imu()] if self.imu_latency else [], maxlen=self.imu_latency + 1)

    def _schedule_pushes(self) -> None:
        dt = self.timestep
        events = []
        for push in self.pushes:
            start = max(0, int(round(push.start / dt)))
            end = start + max(1, int(round(push.duration / dt)))
            events += [(start, push.link, push.force), (end, push.link, np.zeros(3))]
        self._events = sorted(events, key=lambda event: event[0])
        self._event_index = 0

    @property
    def timestep(self) -> float:
        model = getattr(self.inner, "model", None)
        if model is not None and hasattr(model, "opt"):
            return float(model.opt.timestep)
        return float(getattr(self.inner, "timestep", None) or self.inner.description.timestep)

    @property
    def tick(self) -> int:
        """Physics steps since the last reset."""
        return self._tick

    # --- simulation -----------------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        self.inner.reset(q, v)
        self._tick = 0
        self._queue.clear()
        self._event_index = 0
        self._push_force.clear()
        self._user_wrenches.clear()  # the engines' reset clears external wrenches too
        self._start_imu_history()
        self._noise_tick = -1
        self._release()

    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps, applying delayed commands and push changes on their step."""
        end = self._tick + int(n)
        while self._tick < end:
            following = min(end, self._next_event())
            if self.imu_latency:
                following = self._tick + 1
            self.inner.step(following - self._tick)
            self._tick = following
            if self.imu_latency:
                self._imu_history.append(self.inner.imu())
            self._release()

    def _next_event(self) -> float:
        command = self._queue[0][0] if self._queue else math.inf
        push = self._events[self._event_index][0] if self._event_index < len(self._events) else math.inf
        return max(self._tick + 1, min(command, push))

    def _release(self) -> None:
        """Apply commands and push changes due at or before the current physics step."""
        while self._queue and self._queue[0][0] <= self._tick:
            _, kind, payload = self._queue.popleft()
            self._forward(kind, payload)
        while self._event_index < len(self._events) and self._events[self._event_index][0] <= self._tick:
            _, link, force = self._events[self._event_index]
            self._push_force[link] = force
            self._apply_wrench(link)
            self._event_index += 1

    def set_external_wrench(self, link: str, force: np.ndarray, torque: np.ndarray | None = None) -> None:
        """A user wrench, held until changed; pushes on the same link add to it."""
        self._user_wrenches[link] = (np.asarray(force, dtype=float).copy(), np.zeros(3) if torque is None else np.asarray(torque, dtype=float).copy())
        self._apply_wrench(link)

    def _apply_wrench(self, link: str) -> None:
        force, torque = self._user_wrenches.get(link, (np.zeros(3), np.zeros(3)))
        self.inner.set_external_wrench(link, force + self._push_force.get(link, 0.0), torque)

    @property
    def push_force(self) -> dict[str, np.ndarray]:
        """The push currently applied, per link."""
        return {link: force.copy() for link, force in self._push_force.items() if force.any()}

    # --- commands -------------------------------------------------------------------------------
    def set_joint_torques(self, torques: np.ndarray) -> None:
        torques = np.array(torques, dtype=float)
        if torques.shape != (self.dofs,):
            raise ValueError(f"expected {self.dofs} joint torques, got shape {torques.shape}")
        if not np.all(np.isfinite(torques)):
            raise ValueError(f"joint torques must be finite, got {torques}")
        self._command("torques", torques)

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        command.validate(self.dofs)
        scaled = replace(
            command,
            q_ref=np.array(command.q_ref, dtype=float),
            v_ref=np.array(command.v_ref, dtype=float),
            kp=np.asarray(command.kp, dtype=float) * self.kp_scale,
            kd=np.asarray(command.kd, dtype=float) * self.kd_scale,
            tau_ff=np.array(command.tau_ff, dtype=float),
        )
        self._command("impedance", scaled)

    def _command(self, kind: str, payload: Any) -> None:
        if self.latency == 0:
            self._forward(kind, payload)
        else:
            self._queue.append((self._tick + self.latency, kind, payload))

    def _forward(self, kind: str, payload: Any) -> None:
        if kind == "torques":
            self.inner.set_joint_torques(payload)
        else:
            self.inner.set_joint_impedance(payload)

    # --- reads ----------------------------------------------------------------------------------
    def _draw(self) -> dict[str, np.ndarray]:
        """This physics step's noise (drawn once per step, in a fixed order)."""
        if self._noise_tick != self._tick:
            rng, n = self._rng, self.dofs
            self._noise = {
                "position": rng.standard_normal(n) * self.position_noise,
                "velocity": rng.standard_normal(n) * self.velocity_noise,
                "gyro": rng.standard_normal(3) * self.gyro_noise,
                "accelerometer": rng.standard_normal(3) * self.accelerometer_noise,
                "orientation": rng.standard_normal(3) * self.orientation_noise,
            }
            self._noise_tick = self._tick
        return self._noise

    def joint_positions(self) -> np.ndarray:
        return self.inner.joint_positions() + self.position_bias + self._draw()["position"]

    def joint_velocities(self) -> np.ndarray:
        return self.inner.joint_velocities() + self._draw()["velocity"]

    def joint_efforts(self) -> np.ndarray:
        return self.inner.joint_efforts()

    def imu(self) -> ImuReading:
        """The IMU reading ``imu_latency`` physics steps old, with bias and noise."""
        true = self._imu_history[0] if self.imu_latency else self.inner.imu()
        noise = self._draw()
        quaternion = true.quaternion
        if self.orientation_noise:
            quaternion = _quat_multiply(quaternion, _rotation_quaternion(noise["orientation"]))
        return ImuReading(
            quaternion,
            true.angular_velocity + self.gyro_bias + noise["gyro"],
            true.linear_acceleration + self.accelerometer_bias + noise["accelerometer"],
            true.time,
        )

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Engine base state (ground truth) with the noisy joint readings."""
        q, v = self.inner.generalized_state()
        n = self.dofs
        q, v = q.copy(), v.copy()
        noise = self._draw()
        q[-n:] += self.position_bias + noise["position"]
        v[-n:] += noise["velocity"]
        return q, v

    def base_state(self) -> BaseState:
        return self.inner.base_state()

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        return self.inner.link_pose(link)

    def contact_wrench(self, link: str) -> ContactWrench:
        return self.inner.contact_wrench(link)

    # --- identity -------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.inner.name

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.inner.joint_names

    @property
    def floating_base(self) -> bool:
        return self.inner.floating_base

    def time(self) -> float:
        return self.inner.time()

