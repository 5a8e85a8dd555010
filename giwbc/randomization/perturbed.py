"""Robot-level randomization: a Robot wrapper that any simulated robot (MuJoCo or PyBullet) runs through.

:class:`PerturbedRobot` adds what a physics model does not hold, and is the one place giwbc
implements each of these effects (the runtime's ``SimToReal`` knobs for actuator delay and pushes
are turned into randomization entries applied here):

* actuator latency: commands reach the engine ``actuator_latency`` physics steps late;
* PD gain scales on impedance commands;
* sensor noise, bias and IMU latency, through a :class:`~giwbc.robot.noise.SensorModel` built
  from the episode sample (the same model :class:`~giwbc.robot.noise.NoisyRobot` uses);
* a push schedule (world forces on a link, drawn per episode).

It is a ``SimulatedRobot`` itself (``step``, ``reset``, ``set_external_wrench``), so a runtime steps
it exactly as it steps the engine robot; ``step(n)`` splits at the physics steps where a delayed
command, a push start or end falls due (and steps one by one while the IMU is delayed, to sample
it at every step). Base state, link poses and contact wrenches pass through untouched (ground
truth, for rewards), and so do the engine's raw ``sensor(name)`` channels.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from giwbc.randomization.sampling import Push, Sample
from giwbc.robot.interface import ImpedanceCommand, ImuReading, Robot, RobotWrapper
from giwbc.robot.noise import SensorErrors, SensorModel


def sensor_errors(episode: Sample) -> SensorErrors:
    """The sensor part of a randomization episode sample (per-joint noise and bias, IMU latency)."""
    return SensorErrors(
        joint_position_noise=episode["joint_position_noise"].copy(),
        joint_position_bias=episode["joint_position_bias"].copy(),
        joint_velocity_noise=episode["joint_velocity_noise"].copy(),
        gyro_noise=episode.scalar("gyro_noise"),
        gyro_bias=episode["gyro_bias"].copy(),
        accel_noise=episode.scalar("accelerometer_noise"),
        accel_bias=episode["accelerometer_bias"].copy(),
        orientation_noise=episode.scalar("imu_orientation_noise"),
        imu_latency=int(episode.scalar("imu_latency")),
        mounting=episode["imu_mounting"].copy(),
        orientation_bias=episode["imu_orientation_bias"].copy(),
        heading_drift=episode.scalar("imu_heading_drift"),
        imu_dropout=episode.scalar("imu_dropout"),
        sample_jitter=episode.scalar("imu_timestamp_jitter"),
        encoder_resolution=episode.scalar("encoder_resolution"),
    )


class PerturbedRobot(RobotWrapper):
    """Wraps a simulated robot; :meth:`set_perturbations` installs one episode's samples."""

    def __init__(self, robot: Robot) -> None:
        for method in ("step", "reset", "set_external_wrench"):
            if not callable(getattr(robot, method, None)):
                raise TypeError(f"{type(robot).__name__} is not a simulated robot: it has no {method}()")
        super().__init__(robot)
        n = robot.dofs
        self.latency = 0
        self.kp_scale, self.kd_scale = np.ones(n), np.ones(n)
        self.sensors: SensorModel | None = None  # None: readings are the engine's
        self.pushes: tuple[Push, ...] = ()
        description = getattr(robot, "description", None)
        self._has_imu = description is None or getattr(description, "imu_frame", None) is not None
        self._tick = 0
        self._queue: deque[tuple[int, str, Any]] = deque()
        self._events: list[tuple[int, str, np.ndarray, bool]] = []  # (tick, link, force, is_start)
        self._event_index = 0
        self._push_starts = np.zeros(0, dtype=int)
        self._user_wrenches: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._push_force: dict[str, np.ndarray] = {}  # applied from now on
        self._acting: dict[str, np.ndarray] = {}  # applied over the last physics step

    def __getattr__(self, name: str) -> Any:
        """Everything else (``model``, ``data``, ``description``, ``sensor``, ``client``...) is the engine's."""
        if name == "robot":
            raise AttributeError(name)
        return getattr(self.robot, name)

    # --- configuration --------------------------------------------------------------------------
    def set_perturbations(self, physics: Sample | None, episode: Sample | None) -> None:
        """Install the robot-level parts of a physics sample and of an episode sample (``None``: nominal)."""
        n = self.dofs
        if physics is not None:
            self.latency = int(physics.scalar("actuator_latency"))
            self.kp_scale, self.kd_scale = physics["kp_scale"].copy(), physics["kd_scale"].copy()
        else:
            self.latency, self.kp_scale, self.kd_scale = 0, np.ones(n), np.ones(n)
        self.sensors = None
        self.pushes = ()
        if episode is not None:
            errors = sensor_errors(episode)
            if not errors.is_ideal():
                self.sensors = SensorModel(self.robot, errors, np.random.default_rng(episode.noise_seed), imu=self._has_imu)
            self.pushes = episode.pushes
        self._schedule_pushes()

    def postpone_pushes(self) -> None:
        """No push acts until :meth:`start_pushes` (a runtime's start-up before the episode proper)."""
        self._events, self._event_index, self._push_starts = [], 0, np.zeros(0, dtype=int)

    def start_pushes(self) -> None:
        """The episode's pushes from now on: their start times count from this physics step."""
        self._schedule_pushes(origin=self._tick)

    def _schedule_pushes(self, origin: int = 0) -> None:
        dt = self.timestep
        events = []
        for push in self.pushes:
            start = origin + max(0, int(round(push.start / dt)))
            end = start + max(1, int(round(push.duration / dt)))
            events += [(start, push.link, push.force, True), (end, push.link, np.zeros(3), False)]
        self._events = sorted(events, key=lambda event: event[0])
        self._event_index = 0
        self._push_starts = np.array(sorted(tick for tick, _, _, start in events if start), dtype=int)

    @property
    def timestep(self) -> float:
        model = getattr(self.robot, "model", None)
        if model is not None and hasattr(model, "opt"):
            return float(model.opt.timestep)
        return float(getattr(self.robot, "timestep", None) or self.robot.description.timestep)

    @property
    def tick(self) -> int:
        """Physics steps since the last reset."""
        return self._tick

    @property
    def _records_every_step(self) -> bool:
        return self.sensors is not None and self.sensors.errors.latency > 0

    # --- simulation -----------------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        self.robot.reset(q, v)
        self._tick = 0
        self._queue.clear()
        self._event_index = 0
        self._push_force.clear()
        self._acting = {}
        self._user_wrenches.clear()  # the engines' reset clears external wrenches too
        if self.sensors is not None:
            self.sensors.restart()
            if self._records_every_step:
                self.sensors.record()
        self._release()

    def step(self, n: int = 1) -> None:
        """Advance ``n`` physics steps, applying delayed commands and push changes on their step."""
        end = self._tick + int(n)
        every_step = self._records_every_step
        while self._tick < end:
            following = self._tick + 1 if every_step else min(end, self._next_event())
            self._acting = dict(self._push_force)
            self.robot.step(following - self._tick)
            self._tick = following
            if every_step:
                self.sensors.record()
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
            _, link, force, _ = self._events[self._event_index]
            self._push_force[link] = force
            self._apply_wrench(link)
            self._event_index += 1

    def set_external_wrench(self, link: str, force: np.ndarray, torque: np.ndarray | None = None) -> None:
        """A user wrench, held until changed; pushes on the same link add to it."""
        self._user_wrenches[link] = (np.asarray(force, dtype=float).copy(), np.zeros(3) if torque is None else np.asarray(torque, dtype=float).copy())
        self._apply_wrench(link)

    def _apply_wrench(self, link: str) -> None:
        force, torque = self._user_wrenches.get(link, (np.zeros(3), np.zeros(3)))
        self.robot.set_external_wrench(link, force + self._push_force.get(link, 0.0), torque)

    @property
    def push_force(self) -> dict[str, np.ndarray]:
        """The push applied from now on, per link."""
        return {link: force.copy() for link, force in self._push_force.items() if force.any()}

    @property
    def acting_push_force(self) -> np.ndarray:
        """The total push force that acted over the last physics step (world frame, N)."""
        return sum((force for force in self._acting.values()), np.zeros(3))

    @property
    def pushes_applied(self) -> int:
        """Pushes that have acted on the robot since the reset (started before the current physics step)."""
        return int(self._push_starts.searchsorted(self._tick, side="left"))

    # --- commands -------------------------------------------------------------------------------
    def _send_joint_torques(self, torques: np.ndarray) -> None:
        if self.latency == 0:  # (_command's and _forward's path, without their two calls: every controller tick)
            self.robot._send_joint_torques(torques)  # checked by set_joint_torques (a fresh array)
        else:
            self._queue.append((self._tick + self.latency, "torques", torques))

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
            self.robot._send_joint_torques(payload)  # checked by set_joint_torques (a fresh array)
        else:
            self.robot.set_joint_impedance(payload)

    # --- reads ----------------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        return self.robot.joint_positions() if self.sensors is None else self.sensors.joint_positions()

    def joint_velocities(self) -> np.ndarray:
        return self.robot.joint_velocities() if self.sensors is None else self.sensors.joint_velocities()

    def joint_efforts(self) -> np.ndarray:
        return self.robot.joint_efforts() if self.sensors is None else self.sensors.joint_efforts()

    def imu(self) -> ImuReading:
        """The IMU reading ``imu_latency`` physics steps old, with bias and noise."""
        return self.robot.imu() if self.sensors is None else self.sensors.imu()

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Engine base state (ground truth) with the measured joint readings."""
        q, v = self.robot.generalized_state()
        if self.sensors is None:
            return q, v
        n = self.dofs
        q, v = q.copy(), v.copy()
        q[-n:] = self.sensors.joint_positions()
        v[-n:] = self.sensors.joint_velocities()
        return q, v

