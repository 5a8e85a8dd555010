"""The Robot interface over a MuJoCo ``MjData``."""

from __future__ import annotations

import os

import mujoco
import numpy as np

from giwbc.robot.actuator_dynamics import ActuatorDynamics
from giwbc.robot.conventions import pinocchio_to_mujoco, wxyz_to_xyzw
from giwbc.robot.description import RobotDescription
from giwbc.robot.fixed_links import Carrier, carrier, fixed_parents
from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, DescribedRobot, ImuReading, quat_to_matrix
from giwbc.robot.mujoco_model import imu_sensor_names
from giwbc.robot.mujoco_plant import adopt_actuators, bind, plant_from_file

_BIAS_POSITION, _BIAS_VELOCITY = 1, 2  # columns of actuator_biasprm (affine bias: b0 + b1*q + b2*qdot)


def _as_slice(indices: np.ndarray) -> slice | np.ndarray:
    """A slice when the indices are contiguous (a view instead of a gather), else the indices."""
    if len(indices) and np.array_equal(indices, np.arange(indices[0], indices[0] + len(indices))):
        return slice(int(indices[0]), int(indices[0]) + len(indices))
    return indices


class MujocoRobot(DescribedRobot):
    """A robot simulated by MuJoCo, built from a :class:`RobotDescription`.

    Commands are held and evaluated by MuJoCo's actuators at every physics step, the way a
    motor driver evaluates an impedance command at its own rate. :meth:`step` advances physics.
    """

    def __init__(
        self,
        description: RobotDescription,
        model: mujoco.MjModel | str | os.PathLike[str] | None = None,
        *,
        actuator_dynamics: ActuatorDynamics | None = None,
    ) -> None:
        """``model``: the plant, an ``MjModel`` or an MJCF file (default: the description's own
        model). It is checked against the description and bound by name
        (:mod:`giwbc.robot.mujoco_plant`: one PlantMismatchError line naming what does not fit); an
        MJCF file gets the sensors, keyframe and floor it lacks. Its torque actuators are turned
        into giwbc's impedance form in place. ``actuator_dynamics``: lag and torque-speed envelope
        applied to every command per physics step (:mod:`giwbc.robot.actuator_dynamics`)."""
        self.description = description
        if model is None:
            model = description.build_mujoco()
        elif isinstance(model, (str, os.PathLike)):
            model = plant_from_file(description, model)
        self.model = model
        binding = bind(description, model)
        adopt_actuators(description, model, binding)
        self.binding = binding
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._qpos = _as_slice(binding.qpos)
        self._qvel = _as_slice(binding.dofs)
        self._base_qpos, self._base_dof = binding.base_qpos, binding.base_dof
        actuated = description.actuated
        self._actuated = actuated
        self._all_actuated = bool(actuated.all())
        self._acts = _as_slice(binding.actuators)
        # generalized_state's gathers: Pinocchio's q = [p, quat_xyzw, joints], v = [v_world, ω, joints]
        # (the base's linear velocity rotated into its frame afterwards), one fancy index each
        qpos_index, qvel_index = np.arange(m.nq)[self._qpos], np.arange(m.nv)[self._qvel]
        if self.floating_base:
            b, d = self._base_qpos, self._base_dof
            qpos_index = np.concatenate([np.arange(b, b + 3), np.arange(b + 4, b + 7), [b + 3], qpos_index])
            qvel_index = np.concatenate([np.arange(d, d + 6), qvel_index])
        self._q_gather, self._v_gather = qpos_index.astype(np.intp), qvel_index.astype(np.intp)
        self._conjugate = np.empty(4)  # scratch: the base orientation's conjugate (wxyz)
        self._body_ids: dict[str, int] = {}
        self._merged: dict[str, Carrier] = {}  # links the plant merged into a parent, and where they sit in it
        self._sensor_slices = {
            m.sensor(i).name: slice(int(m.sensor_adr[i]), int(m.sensor_adr[i] + m.sensor_dim[i])) for i in range(m.nsensor)
        }
        names = imu_sensor_names()  # the IMU's three channels, when the plant has them all (imu(): one slice each)
        channels = [self._sensor_slices.get(names[key]) for key in ("quaternion", "angular_velocity", "linear_acceleration")]
        self._imu_slices = None if None in channels else tuple(channels)
        self._impedance_active = True  # biasprm may hold gains until the first torque command clears them
        self._wrench = np.zeros(6)
        self.actuator_dynamics = actuator_dynamics if actuator_dynamics is not None and actuator_dynamics.active else None
        if self.actuator_dynamics is not None and len(self.actuator_dynamics.lag) != int(actuated.sum()):
            raise ValueError(f"actuator dynamics for {len(self.actuator_dynamics.lag)} actuators, the robot has {int(actuated.sum())}")
        n = int(actuated.sum())
        self._command = np.zeros(n)  # the torque command, or the impedance's feed-forward part
        self._kp, self._kd, self._q_ref, self._v_ref = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
        self._delivered = np.zeros(n)  # the torque the lagged actuator delivers
        self.reset()

    # --- identity -------------------------------------------------------------------------
    def time(self) -> float:
        return float(self.data.time)

    # --- simulation -----------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        """Reset to the default standing pose, or to a Pinocchio-convention state ``(q, v)``."""
        mujoco.mj_resetDataKeyframe(self.model, self.data, 0)
        if q is not None:
            q = np.asarray(q, float)
            v = np.zeros(len(q) - 1 if self.floating_base else len(q)) if v is None else np.asarray(v, float)
            if self.floating_base:
                qpos, qvel = pinocchio_to_mujoco(q, v)
                b, d = self._base_qpos, self._base_dof
                self.data.qpos[b: b + 7] = qpos[:7]
                self.data.qvel[d: d + 6] = qvel[:6]
                qpos, qvel = qpos[7:], qvel[6:]
            else:
                qpos, qvel = q, v
            self.data.qpos[self._qpos] = qpos
            self.data.qvel[self._qvel] = qvel
        self._delivered[:] = 0.0
        self.set_joint_torques(np.zeros(self.dofs))
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        """Advance physics by ``n`` steps, holding the current command (through the actuator
        dynamics, when the plant has them, evaluated at every step)."""
        if self.actuator_dynamics is None:
            mujoco.mj_step(self.model, self.data, nstep=n)
            return
        dynamics, data = self.actuator_dynamics, self.data
        kept = dynamics.retention(self.model.opt.timestep)
        for _ in range(n):
            speed = data.qvel[self._qvel][self._actuated]
            command = self._command
            if self._impedance_active:
                position = data.qpos[self._qpos][self._actuated]
                command = command + self._kp * (self._q_ref - position) + self._kd * (self._v_ref - speed)
            delivered = dynamics.available(kept * self._delivered + (1.0 - kept) * command, speed)
            self._delivered = delivered
            data.ctrl[self._acts] = delivered
            mujoco.mj_step(self.model, data)

    def set_external_wrench(self, link: str, force: np.ndarray, torque: np.ndarray | None = None) -> None:
        """World-frame force (at the link's centre of mass) and torque on a link, held until changed."""
        body = self._body_id(link)
        self.data.xfrc_applied[body, :3] = force
        self.data.xfrc_applied[body, 3:] = 0.0 if torque is None else torque

    # --- joints ---------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        return self.data.qpos[self._qpos].copy()

    def joint_velocities(self) -> np.ndarray:
        return self.data.qvel[self._qvel].copy()

    def joint_efforts(self) -> np.ndarray:
        if self._all_actuated:  # (the zeros below all overwritten: the forces' copy)
            return self.data.actuator_force[self._acts].copy()
        efforts = np.zeros(self.dofs)
        efforts[self._actuated] = self.data.actuator_force[self._acts]
        return efforts

    # --- base, links, contacts, sensors -----------------------------------------------------
    def base_state(self) -> BaseState:
        if not self.floating_base:
            body = self._body_id(self.description.base_link)
            xquat = self.data.xquat[body]
            return BaseState(self.data.xpos[body].copy(), wxyz_to_xyzw(xquat), np.zeros(3), np.zeros(3))
        b, d = self._base_qpos, self._base_dof
        qpos, qvel = self.data.qpos[b: b + 7], self.data.qvel[d: d + 6]
        quaternion = wxyz_to_xyzw(qpos[3:7])
        return BaseState(qpos[:3].copy(), quaternion, qvel[:3].copy(), quat_to_matrix(quaternion) @ qvel[3:6])

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        data = self.data
        q, v = data.qpos[self._q_gather], data.qvel[self._v_gather]  # new arrays, the quaternion reordered
        if not self.floating_base:
            return q, v
        b, d = self._base_qpos, self._base_dof
        conjugate = self._conjugate
        mujoco.mju_negQuat(conjugate, data.qpos[b + 3: b + 7])
        mujoco.mju_rotVecQuat(v[:3], data.qvel[d: d + 3], conjugate)
        return q, v

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a link's frame (a link the plant merged into its parent: from the body carrying it)."""
        body = self._body_id(link)
        position, rotation = self.data.xpos[body].copy(), self.data.xmat[body].reshape(3, 3).copy()
        held = self._merged.get(link)
        if held is None:
            return position, rotation
        return position + rotation @ held.position, rotation @ held.rotation

    def contact_wrench(self, link: str) -> ContactWrench:
        body = self._body_id(link)
        data = self.data
        if data.ncon == 0:
            return ContactWrench(np.zeros(3), np.zeros(3), False)
        # Plain floats over the few contacts (numpy calls on a handful of rows cost more than the
        # arithmetic; the walker reads both feet every tick), summed in the order numpy did.
        # Sign: +1 when the body owns geom2 (the force acts on geom2), −1 when it owns geom1.
        contacts, geom_body = data.contact, self.model.geom_bodyid
        geom1, geom2 = contacts.geom1.tolist(), contacts.geom2.tolist()
        force = torque = None
        wrench = self._wrench
        frames = positions = None
        x, y, z = data.xpos[body].tolist()
        for index, (g1, g2) in enumerate(zip(geom1, geom2)):
            sign = 1.0 if geom_body[g2] == body else -1.0 if geom_body[g1] == body else 0.0
            if sign == 0.0:
                continue
            if frames is None:
                frames, positions = contacts.frame.tolist(), contacts.pos.tolist()
            mujoco.mj_contactForce(self.model, data, index, wrench)
            f0, f1, f2 = wrench[:3].tolist()
            r = frames[index]  # the contact frame's rows are its axes (normal first)
            w = (sign * (r[0] * f0 + r[3] * f1 + r[6] * f2), sign * (r[1] * f0 + r[4] * f1 + r[7] * f2), sign * (r[2] * f0 + r[5] * f1 + r[8] * f2))
            px, py, pz = positions[index]
            a0, a1, a2 = px - x, py - y, pz - z
            m = (a1 * w[2] - a2 * w[1], a2 * w[0] - a0 * w[2], a0 * w[1] - a1 * w[0])
            if force is None:
                force, torque = w, m
            else:
                force = (force[0] + w[0], force[1] + w[1], force[2] + w[2])
                torque = (torque[0] + m[0], torque[1] + m[1], torque[2] + m[2])
        if force is None:
            return ContactWrench(np.zeros(3), np.zeros(3), False)
        return ContactWrench(np.array(force), np.array(torque), True)

    def imu(self) -> ImuReading:
        if self._imu_slices is not None:  # (the sensor() reads below, without their name look-ups: every physics step of a sensor model)
            sensordata = self.data.sensordata
            quaternion, angular_velocity, linear_acceleration = self._imu_slices
            return ImuReading(wxyz_to_xyzw(sensordata[quaternion]), sensordata[angular_velocity].copy(),
                              sensordata[linear_acceleration].copy(), float(self.data.time))
        names = imu_sensor_names()  # (raises, naming the missing channel)
        quaternion = wxyz_to_xyzw(self.sensor(names["quaternion"]))
        return ImuReading(
            quaternion, self.sensor(names["angular_velocity"]), self.sensor(names["linear_acceleration"]), self.time()
        )

    def sensor(self, name: str) -> np.ndarray:
        """Raw reading of a named MuJoCo sensor (IMU channels, foot force/torque/touch)."""
        try:
            return self.data.sensordata[self._sensor_slices[name]].copy()
        except KeyError:
            raise KeyError(f"no sensor {name!r}; available: {sorted(self._sensor_slices)}") from None

    # --- commands -------------------------------------------------------------------------
    def _send_joint_torques(self, torques: np.ndarray) -> None:
        if self._impedance_active:  # torque mode: no stiffness or damping in the actuator
            bias = self.model.actuator_biasprm
            bias[self._acts, _BIAS_POSITION] = 0.0
            bias[self._acts, _BIAS_VELOCITY] = 0.0
            self._impedance_active = False
        # (torques is the fresh array set_joint_torques checked: kept as it is when every joint is driven)
        self._command = torques if self._all_actuated else torques[self._actuated]
        if self.actuator_dynamics is None:
            self.data.ctrl[self._acts] = self._command

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        command.validate(self.dofs)
        actuated = self._actuated
        self._impedance_active = True
        self._kp, self._kd = command.kp[actuated], command.kd[actuated]
        self._q_ref, self._v_ref = command.q_ref[actuated], command.v_ref[actuated]
        self._command = np.asarray(command.tau_ff, float)[actuated]
        if self.actuator_dynamics is not None:  # the PD is evaluated in step(), behind the lag
            return
        bias = self.model.actuator_biasprm
        bias[self._acts, _BIAS_POSITION] = -command.kp[actuated]
        bias[self._acts, _BIAS_VELOCITY] = -command.kd[actuated]
        self.data.ctrl[self._acts] = (command.kp * command.q_ref + command.kd * command.v_ref + command.tau_ff)[actuated]

    def set_actuator_dynamics(self, dynamics: ActuatorDynamics | None) -> None:
        """Change the actuators' lag and envelope (per-episode randomization); the command in force is kept."""
        dynamics = dynamics if dynamics is not None and dynamics.active else None
        if dynamics is not None and len(dynamics.lag) != len(self._command):
            raise ValueError(f"actuator dynamics for {len(dynamics.lag)} actuators, the robot has {len(self._command)}")
        was = self.actuator_dynamics
        self.actuator_dynamics = dynamics
        if was is None and dynamics is not None:
            self._delivered = self.data.actuator_force[self._acts].copy()  # the lag starts from the torque delivered now
        if (was is None) == (dynamics is None) or not self._impedance_active:
            if dynamics is None and not self._impedance_active:
                self.data.ctrl[self._acts] = self._command
            return
        bias = self.model.actuator_biasprm
        if dynamics is not None:  # the PD moves from MuJoCo's bias into step()
            bias[self._acts, _BIAS_POSITION] = 0.0
            bias[self._acts, _BIAS_VELOCITY] = 0.0
        else:
            bias[self._acts, _BIAS_POSITION] = -self._kp
            bias[self._acts, _BIAS_VELOCITY] = -self._kd
            self.data.ctrl[self._acts] = self._kp * self._q_ref + self._kd * self._v_ref + self._command

    # --- helpers --------------------------------------------------------------------------
    def _urdf_links(self) -> set[str]:
        return set(fixed_parents(self.description.urdf_path))

    def _body_id(self, link: str) -> int:
        body = self._body_ids.get(link)
        if body is None:
            body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, link)
            if body < 0 and link in self._urdf_links():  # merged by the plant into the body that carries it
                held = carrier(self.description.urdf_path, frozenset(self.model.body(i).name for i in range(self.model.nbody)), link)
                self._merged[link] = held
                body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, held.body)
            if body < 0:
                raise KeyError(f"robot {self.name!r} has no link {link!r}")
            self._body_ids[link] = body
        return body
