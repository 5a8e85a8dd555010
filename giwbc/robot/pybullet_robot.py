"""The Robot interface over PyBullet: a second physics engine built from the same robot description.

Simulation-facing methods mirror :class:`~giwbc.robot.mujoco_robot.MujocoRobot` (``step(n)``,
``reset(q, v)``, ``set_external_wrench``, ``sensor(name)``), so a runtime steps either engine the
same way. Differences from the MuJoCo model that no setting removes, measured in the tests:

* **Armature.** PyBullet has no reflected rotor inertia. By default (``armature="link"``) each
  joint's armature is added to its child link's inertia about the joint axis
  (:meth:`PybulletRobot.set_armature`). The joint then gains the armature on its mass-matrix
  diagonal, but on a floating base the added inertia also pushes back on the base (a real rotor
  sits on the parent and pushes back by ``armature / gear ratio`` only). Measured on the G1 in
  free flight (tests/test_pybullet_robot.py): the joint-space inverse inertia is 0.9-1.8x that
  of the Pinocchio/MuJoCo model with armature (1.3-23x with no armature at all), and a torque on
  the limp robot's pelvis puts up to ~26 % of the angular momentum into the added inertias.
  ``armature="ignore"`` leaves the URDF inertias alone: the G1 then still stands, but its wrist
  and shoulder-yaw joints chatter at tens of rad/s under the description's PD hold, explicit
  damping on links of ~1e-4 kg m² at 2 ms being past the stability bound ``kd dt / I < 2``
  (MuJoCo is spared by the armature and by treating kd implicitly).
* **Impedance.** ``kp (q_ref - q) + kd (v_ref - v) + tau_ff`` is evaluated from the state at the
  start of each physics step, clipped to the effort limits and applied as a torque (explicit),
  where MuJoCo's ``implicitfast`` treats the kd term implicitly; torque and impedance commands
  giving the same torque give bit-identical steps here. ``joint_efforts()`` is that clipped torque.
* **Integration.** Bullet's multibody integrator does not conserve momentum exactly (a limp G1
  tumbling in free flight drifts ~1 % in 0.2 s); a held external wrench changes the momentum by
  ``F t`` to 0.1 % over 20 ms.
* **Contacts.** Bullet's contacts are rigid with Baumgarte stabilisation, MuJoCo's are soft: the
  feet sink differently (sub-millimetre here). Friction combines as the product of the two
  bodies' coefficients (MuJoCo takes the maximum): the feet and the whole-body shapes get 1.0, the
  floor the description's. The whole-body shapes get restitution 0 (no bounce between links; the
  feet keep 1 so that the floor's randomized restitution applies to them). Both engines build the
  same primitives (tests/test_collision.py: link-to-floor distances agree to 1e-6 m).
* **Foot force/torque sensors** (``sensor("left_foot_force")``) come from PyBullet's joint
  reaction at the foot link's joint (reported in the link's inertial frame, torque about its CoM),
  moved to the sole centre: the same convention as MuJoCo's force/torque sites (the wrench the
  parent exerts on the foot link, in the foot frame), so they include the foot's own weight.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping

import numpy as np

from giwbc.robot.description import RobotDescription
from giwbc.robot.interface import BaseState, ContactWrench, ImpedanceCommand, DescribedRobot, ImuReading, quat_to_matrix
from giwbc.robot.mujoco_model import foot_sensor_names, imu_sensor_names
from giwbc.robot.pybullet_model import LinkInertial, PybulletClient, add_floor, load_robot, pybullet_urdf, require_pybullet
from giwbc.robot.so3 import quat_conjugate, quat_multiply

STANDARD_GRAVITY = np.array([0.0, 0.0, -9.81])
FEET_FRICTION = 1.0  # Bullet multiplies the two coefficients: floor friction x 1.0 = the description's


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` for two 3-vectors (``np.cross`` costs ~10x more on single vectors, on every physics step here)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _urdf_link_mass(urdf: str, link: str) -> float:
    for element in ET.fromstring(urdf).iter("link"):
        if element.get("name") == link:
            mass = element.find("inertial/mass")
            return float(mass.get("value", 0.0)) if mass is not None else 0.0
    return 0.0


class PybulletRobot(DescribedRobot):
    """A robot simulated by PyBullet (one DIRECT server per instance unless ``client`` is given).

    ``armature``: ``"link"`` (default) adds each joint's armature to the child link's inertia about
    the joint axis; ``"ignore"`` drops it (see the module docstring). ``visuals`` keeps the URDF
    meshes (slow to load, only useful for rendering). ``inertials`` overrides link masses and
    centres of mass at load time (:meth:`reload` changes them later).
    """

    def __init__(
        self,
        description: RobotDescription,
        client: int | PybulletClient | None = None,
        *,
        armature: str = "link",
        visuals: bool = False,
        floor: bool = True,
        inertials: Mapping[str, LinkInertial] | None = None,
        solver_iterations: int | None = None,
    ) -> None:
        if armature not in ("link", "ignore"):
            raise ValueError(f"armature must be 'link' or 'ignore', got {armature!r}")
        require_pybullet()
        self.description = description
        self.client = client if isinstance(client, PybulletClient) else PybulletClient(client)
        self._armature_mode = armature
        self._visuals = visuals
        self._urdf_source = description.urdf_text()  # kept for reloads
        self.dt = description.timestep
        self.client.setPhysicsEngineParameter(fixedTimeStep=self.dt, numSubSteps=0)
        if solver_iterations is not None:
            self.client.setPhysicsEngineParameter(numSolverIterations=int(solver_iterations))
        self.gravity = STANDARD_GRAVITY.copy()
        self.client.setGravity(*self.gravity)
        self.floor = add_floor(self.client, description.floor_friction) if floor and description.floating_base else None
        n = description.dofs
        self.effort_limits = description.effort_limits.copy()  # mutable: actuator-strength randomization
        self.joint_friction = np.zeros(n)  # Coulomb friction torque per joint, applied by Bullet's motors
        self.joint_damping = np.zeros(n)  # viscous, Bullet's jointDamping
        self.armature = np.array([j.armature for j in description.joints]) if armature == "link" else np.zeros(n)
        self._kp, self._kd = np.zeros(n), np.zeros(n)
        self._q_ref, self._v_ref, self._tau_ff = np.zeros(n), np.zeros(n), np.zeros(n)
        self._efforts = np.zeros(n)
        self._wrenches: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # link index -> world force, torque
        self._steps = 0
        self._imu_velocity: np.ndarray | None = None  # IMU-point velocity before the last physics step
        self._imu_acceleration = np.zeros(3)
        self.body = -1
        self._load(inertials)

    # --- building ---------------------------------------------------------------------------
    def _load(self, inertials: Mapping[str, LinkInertial] | None) -> None:
        c, description = self.client, self.description
        urdf = pybullet_urdf(description, visuals=self._visuals, inertials=inertials, source=self._urdf_source)
        self.body = load_robot(c, description, urdf, description.default_base_position)
        self._inertials = dict(inertials or {})
        names = {}
        self._link_index = {description.base_link: -1}
        for index in range(c.getNumJoints(self.body)):
            info = c.getJointInfo(self.body, index)
            names[info[1].decode()] = index
            self._link_index[info[12].decode()] = index
        missing = [j for j in description.joint_names if j not in names]
        if missing:
            raise ValueError(f"PyBullet model of {description.name!r} lacks joints {missing}")
        self._joints = [names[j] for j in description.joint_names]
        self._pb = require_pybullet()
        for link in [-1, *range(c.getNumJoints(self.body))]:
            c.changeDynamics(self.body, link, linearDamping=0.0, angularDamping=0.0, jointDamping=0.0)
        for shape in description.collision:  # the floor's friction, as the feet; no bounce, even between links
            c.changeDynamics(self.body, self._link_index[shape.link], lateralFriction=FEET_FRICTION, restitution=0.0)
        for contact in description.contacts:
            c.changeDynamics(self.body, self._link_index[contact.link], lateralFriction=FEET_FRICTION, restitution=1.0)
        links = [-1, *range(c.getNumJoints(self.body))]
        self._loaded_mass = {link: c.getDynamicsInfo(self.body, link)[0] for link in links}
        self._loaded_inertia = {link: np.array(c.getDynamicsInfo(self.body, link)[2]) for link in links}
        self._mass_ratio = dict.fromkeys(links, 1.0)
        self._armature_inertia: dict[int, np.ndarray] = {}
        self.set_armature(self.armature)
        self.set_joint_damping(self.joint_damping)
        self._base_inertial = self._inertial_frame(-1)
        self._fixed_base_mass = _urdf_link_mass(urdf, description.base_link)
        imu = description.imu_frame
        self._imu_link = self._link_index[imu] if imu is not None else -1
        self._foot_links = {c.name: self._link_index[c.link] for c in description.contacts}
        for index in self._foot_links.values():
            c.enableJointForceTorqueSensor(self.body, index, 1)
        self._apply_joint_friction()
        self.reset()

    def _inertial_frame(self, link: int) -> tuple[np.ndarray, np.ndarray]:
        """Position and quaternion of a link's inertial (PyBullet body) frame in its URDF frame."""
        info = self.client.getDynamicsInfo(self.body, link)
        return np.array(info[3]), np.array(info[4])

    def set_armature(self, armature: np.ndarray) -> None:
        """Emulate per-joint armature by adding it to each child link's inertia about the joint axis.

        PyBullet keeps a link inertia as a diagonal in an inertial frame it chose at loading (and
        its URDF importer zeroes a tensor that breaks the triangle inequality, as ``I + arm a a^T``
        does on light links), so the armature goes in through ``changeDynamics``, spread over that
        diagonal as ``arm a_i^2 / sum(a^4)`` (``a`` the joint axis in that frame): ``a^T dI a = arm``
        exactly. Written over the loaded inertia, so calls do not accumulate.
        """
        armature = np.asarray(armature, dtype=float)
        if armature.shape != (self.dofs,) or np.any(armature < 0) or not np.all(np.isfinite(armature)):
            raise ValueError(f"armature must be {self.dofs} finite values >= 0")
        if self._armature_mode == "ignore" and armature.any():
            raise ValueError("this robot was built with armature='ignore': it cannot take an armature")
        c = self.client
        for joint, value in zip(self._joints, armature):
            axis = np.array(c.getJointInfo(self.body, joint)[13])  # PyBullet gives it in the inertial frame
            squares = (axis / np.linalg.norm(axis)) ** 2
            self._armature_inertia[joint] = value * squares / np.sum(squares**2)
            self._write_inertia(joint)
        self.armature = armature.copy()

    def set_link_masses(self, masses: Mapping[str, float]) -> None:
        """Set link masses, scaling each link's rotational inertia by the same factor (armature kept)."""
        for link, mass in masses.items():
            index = self.link_index(link)
            mass = float(mass)
            if not (mass >= 0 and np.isfinite(mass)):
                raise ValueError(f"mass of {link!r} must be finite and >= 0, got {mass}")
            loaded = self._loaded_mass[index]
            if index < 0 and not self.floating_base:
                self._fixed_base_mass = mass  # PyBullet keeps a fixed base massless
                continue
            if loaded <= 0:
                if mass > 0:
                    raise ValueError(f"link {link!r} is massless in the model; it cannot be given a mass")
                continue
            self._mass_ratio[index] = mass / loaded
            self._write_inertia(index)

    def _write_inertia(self, index: int) -> None:
        diagonal = self._loaded_inertia[index] * self._mass_ratio[index] + self._armature_inertia.get(index, 0.0)
        mass = self._loaded_mass[index] * self._mass_ratio[index]
        self.client.changeDynamics(self.body, index, mass=mass, localInertiaDiagonal=list(diagonal))

    def set_joint_damping(self, damping: np.ndarray) -> None:
        """Viscous joint damping (N m s/rad), Bullet's own ``jointDamping`` (applied explicitly)."""
        damping = np.asarray(damping, dtype=float)
        if damping.shape != (self.dofs,) or np.any(damping < 0) or not np.all(np.isfinite(damping)):
            raise ValueError(f"joint damping must be {self.dofs} finite values >= 0")
        for joint, value in zip(self._joints, damping):
            self.client.changeDynamics(self.body, joint, jointDamping=float(value))
        self.joint_damping = damping.copy()

    def set_ground(self, friction: float | None = None, restitution: float | None = None) -> None:
        """Floor friction and restitution. Bullet multiplies the two bodies' values; the feet hold 1."""
        if self.floor is None:
            raise ValueError(f"robot {self.name!r} has no floor")
        if friction is not None:
            self.client.changeDynamics(self.floor, -1, lateralFriction=float(friction))
        if restitution is not None:
            self.client.changeDynamics(self.floor, -1, restitution=float(restitution))

    def reload(self, inertials: Mapping[str, LinkInertial] | None = None) -> None:
        """Reload the robot with new link masses / centres of mass (PyBullet cannot move a CoM in place).

        Masses are those of ``inertials`` (URDF values elsewhere): earlier :meth:`set_link_masses`
        calls are dropped. Armature, joint damping and friction, effort limits, gravity and the
        floor are kept. The state is reset to the default pose. Loading costs ~2 ms for the G1.
        """
        self.client.removeBody(self.body)
        self._load(inertials)

    def close(self) -> None:
        """Disconnect the physics server if this robot started it."""
        self.client.close()

    def __enter__(self) -> "PybulletRobot":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may be gone
            pass

    # --- identity -------------------------------------------------------------------------
    def time(self) -> float:
        return self._steps * self.dt

    @property
    def timestep(self) -> float:
        """Physics step, s (the description's)."""
        return self.dt

    @property
    def link_names(self) -> tuple[str, ...]:
        return tuple(self._link_index)

    def link_index(self, link: str) -> int:
        """PyBullet link index of a URDF link (-1 for the base)."""
        try:
            return self._link_index[link]
        except KeyError:
            raise KeyError(f"robot {self.name!r} has no link {link!r}") from None

    # --- simulation -----------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None, v: np.ndarray | None = None) -> None:
        """Reset to the default standing pose, or to a Pinocchio-convention state ``(q, v)``."""
        description = self.description
        q = description.default_configuration() if q is None else np.asarray(q, dtype=float)
        nq = description.dofs + (7 if self.floating_base else 0)
        nv = description.dofs + (6 if self.floating_base else 0)
        v = np.zeros(nv) if v is None else np.asarray(v, dtype=float)
        if q.shape != (nq,) or v.shape != (nv,):
            raise ValueError(f"reset expects q of shape ({nq},) and v of shape ({nv},), got {q.shape} and {v.shape}")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ValueError("reset state must be finite")
        c = self.client
        if self.floating_base:
            quaternion = q[3:7] / np.linalg.norm(q[3:7])
            rotation = quat_to_matrix(quaternion)
            offset, inertial_quat = self._base_inertial
            lever = rotation @ offset
            angular = rotation @ v[3:6]
            c.resetBasePositionAndOrientation(self.body, list(q[:3] + lever), list(quat_multiply(quaternion, inertial_quat)))
            c.resetBaseVelocity(self.body, list(rotation @ v[:3] + cross3(angular, lever)), list(angular))
            qj, vj = q[7:], v[6:]
        else:
            qj, vj = q, v
        c.resetJointStatesMultiDof(self.body, self._joints, [[x] for x in qj], targetVelocities=[[x] for x in vj])
        self._steps = 0
        self._imu_velocity = None
        self._imu_acceleration = np.zeros(3)
        self._wrenches.clear()  # as MuJoCo's reset clears xfrc_applied
        self.set_joint_torques(np.zeros(self.dofs))

    def step(self, n: int = 1) -> None:
        """Advance physics by ``n`` steps, re-evaluating the impedance command at every step."""
        c, n = self.client, int(n)
        for index in range(n):
            if index == n - 1:  # the IMU differences its velocity over the last step
                self._imu_velocity = self._imu_point_velocity()
            self._apply_torques()
            for link, (force, torque) in self._wrenches.items():  # Bullet clears them after every step
                com = c.getBasePositionAndOrientation(self.body)[0] if link < 0 else c.getLinkState(self.body, link)[0]
                c.applyExternalForce(self.body, link, list(force), list(com), self._pb.WORLD_FRAME)
                c.applyExternalTorque(self.body, link, list(torque), self._pb.WORLD_FRAME)
            c.stepSimulation()
            self._steps += 1
        if n > 0 and self._imu_velocity is not None:
            self._imu_acceleration = (self._imu_point_velocity() - self._imu_velocity) / self.dt

    def set_external_wrench(self, link: str, force: np.ndarray, torque: np.ndarray | None = None) -> None:
        """World-frame force (at the link's centre of mass) and torque on a link, held until changed."""
        index = self.link_index(link)
        force = np.asarray(force, dtype=float).reshape(3)
        torque = np.zeros(3) if torque is None else np.asarray(torque, dtype=float).reshape(3)
        if not (np.all(np.isfinite(force)) and np.all(np.isfinite(torque))):
            raise ValueError("external wrench must be finite")
        if force.any() or torque.any():
            self._wrenches[index] = (force, torque)
        else:
            self._wrenches.pop(index, None)

    def set_gravity(self, gravity: np.ndarray) -> None:
        self.gravity = np.asarray(gravity, dtype=float).reshape(3).copy()
        self.client.setGravity(*self.gravity)

    def set_joint_friction(self, friction: np.ndarray) -> None:
        """Coulomb friction torque per joint (>= 0), applied by Bullet's velocity motors at zero target."""
        friction = np.asarray(friction, dtype=float)
        if friction.shape != (self.dofs,) or np.any(friction < 0) or not np.all(np.isfinite(friction)):
            raise ValueError(f"joint friction must be {self.dofs} finite values >= 0")
        self.joint_friction = friction.copy()
        self._apply_joint_friction()

    def _apply_joint_friction(self) -> None:
        self.client.setJointMotorControlArray(
            self.body, self._joints, self._pb.VELOCITY_CONTROL, targetVelocities=[0.0] * self.dofs, forces=list(self.joint_friction)
        )

    def link_mass(self, link: str) -> float:
        """Mass of a link as simulated (a fixed base reports the URDF mass; PyBullet stores it as 0)."""
        index = self.link_index(link)
        if index < 0 and not self.floating_base:
            return self._fixed_base_mass
        return float(self.client.getDynamicsInfo(self.body, index)[0])

    def total_mass(self) -> float:
        return float(sum(self.link_mass(link) for link in self._link_index))

    # --- joints ---------------------------------------------------------------------------
    def _joint_states(self) -> tuple[np.ndarray, np.ndarray]:
        states = self.client.getJointStates(self.body, self._joints)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def joint_positions(self) -> np.ndarray:
        return self._joint_states()[0]

    def joint_velocities(self) -> np.ndarray:
        return self._joint_states()[1]

    def joint_efforts(self) -> np.ndarray:
        """The torques applied at the last physics step (after clipping), like MuJoCo's actuator force."""
        return self._efforts.copy()

    # --- base, links, contacts, sensors -----------------------------------------------------
    def base_state(self) -> BaseState:
        c = self.client
        com, com_quat = (np.array(x) for x in c.getBasePositionAndOrientation(self.body))
        offset, inertial_quat = self._base_inertial
        quaternion = quat_multiply(com_quat, quat_conjugate(inertial_quat))
        quaternion /= np.linalg.norm(quaternion)
        position = com - quat_to_matrix(quaternion) @ offset
        if not self.floating_base:
            return BaseState(position, quaternion, np.zeros(3), np.zeros(3))
        linear, angular = (np.array(x) for x in c.getBaseVelocity(self.body))
        return BaseState(position, quaternion, linear + cross3(angular, position - com), angular)

    def generalized_state(self) -> tuple[np.ndarray, np.ndarray]:
        qj, vj = self._joint_states()
        if not self.floating_base:
            return qj, vj
        base = self.base_state()
        rotation_t = base.rotation.T
        q = np.concatenate([base.position, base.quaternion, qj])
        return q, np.concatenate([rotation_t @ base.linear_velocity, rotation_t @ base.angular_velocity, vj])

    def _link_frame(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        if index < 0:
            base = self.base_state()
            return base.position, base.quaternion
        state = self.client.getLinkState(self.body, index, computeForwardKinematics=1)
        return np.array(state[4]), np.array(state[5])

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World position and rotation of the URDF link frame (PyBullet's own link frame is the CoM frame)."""
        position, quaternion = self._link_frame(self.link_index(link))
        return position, quat_to_matrix(quaternion)

    def link_velocity(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World linear velocity of the link frame's origin and world angular velocity."""
        index = self.link_index(link)
        if index < 0:
            base = self.base_state()
            return base.linear_velocity, base.angular_velocity
        state = self.client.getLinkState(self.body, index, computeLinkVelocity=1, computeForwardKinematics=1)
        com, origin, linear, angular = (np.array(state[i]) for i in (0, 4, 6, 7))
        return linear + cross3(angular, origin - com), angular

    def contact_wrench(self, link: str) -> ContactWrench:
        index = self.link_index(link)
        points = self.client.getContactPoints(bodyA=self.body, linkIndexA=index)
        if not points:
            return ContactWrench(np.zeros(3), np.zeros(3), False)
        origin, _ = self._link_frame(index)
        # (position on A, normal on B pointing to A, normal force, friction 1, direction 1, friction 2, direction 2)
        position = np.array([p[5] for p in points])
        forces = (
            np.array([p[9] for p in points])[:, None] * np.array([p[7] for p in points])
            + np.array([p[10] for p in points])[:, None] * np.array([p[11] for p in points])
            + np.array([p[12] for p in points])[:, None] * np.array([p[13] for p in points])
        )
        torque = np.cross(position - origin, forces).sum(axis=0)
        return ContactWrench(forces.sum(axis=0), torque, True)

    def _imu_point_velocity(self) -> np.ndarray:
        if self._imu_link < 0:
            return self.base_state().linear_velocity
        state = self.client.getLinkState(self.body, self._imu_link, computeLinkVelocity=1, computeForwardKinematics=1)
        com, origin, linear, angular = (np.array(state[i]) for i in (0, 4, 6, 7))
        return linear + cross3(angular, origin - com)

    def imu(self) -> ImuReading:
        """IMU-frame readings: specific force ``R^T (a - g)``, ``a`` differenced over the last physics step."""
        if self._imu_link < 0:
            base = self.base_state()
            quaternion, angular = base.quaternion, base.angular_velocity
        else:
            state = self.client.getLinkState(self.body, self._imu_link, computeLinkVelocity=1, computeForwardKinematics=1)
            quaternion, angular = np.array(state[5]), np.array(state[7])
        rotation_t = quat_to_matrix(quaternion).T
        specific_force = rotation_t @ (self._imu_acceleration - self.gravity)
        return ImuReading(quaternion, rotation_t @ angular, specific_force, self.time())

    def sensor(self, name: str) -> np.ndarray:
        """Readings under the MuJoCo model's sensor names (``imu_quat`` is ``(w, x, y, z)`` as there)."""
        imu_names = imu_sensor_names()
        if name in imu_names.values():
            reading = self.imu()
            if name == imu_names["quaternion"]:
                x, y, z, w = reading.quaternion
                return np.array([w, x, y, z])
            return reading.angular_velocity if name == imu_names["angular_velocity"] else reading.linear_acceleration
        for contact in self.description.contacts:
            names = foot_sensor_names(contact.name)
            if name == names["touch"]:
                wrench = self.contact_wrench(contact.link)
                _, rotation = self.link_pose(contact.link)
                return np.array([max(0.0, float((rotation.T @ wrench.force)[2]))])
            if name in (names["force"], names["torque"]):
                force, torque = self._foot_reaction(contact.name)
                return force if name == names["force"] else torque
        available = sorted(imu_names.values()) + sorted(
            n for c in self.description.contacts for n in foot_sensor_names(c.name).values()
        )
        raise KeyError(f"no sensor {name!r}; available: {available}")

    def _foot_reaction(self, contact_name: str) -> tuple[np.ndarray, np.ndarray]:
        """Force and torque the parent exerts on a foot link, about the sole centre, in the foot frame."""
        contact = self.description.contact(contact_name)
        index = self._foot_links[contact_name]
        reaction = np.array(self.client.getJointState(self.body, index)[2])
        # Bullet reports the parent's force on the child in the child's inertial frame, torque about the CoM.
        com, inertial_quat = self._inertial_frame(index)
        rotation = quat_to_matrix(inertial_quat)
        force, torque_com = rotation @ reaction[:3], rotation @ reaction[3:]
        return force, torque_com - cross3(np.asarray(contact.center, dtype=float) - com, force)

    # --- commands -------------------------------------------------------------------------
    def _send_joint_torques(self, torques: np.ndarray) -> None:
        self._kp[:] = 0.0
        self._kd[:] = 0.0
        self._q_ref[:] = 0.0
        self._v_ref[:] = 0.0
        self._tau_ff[:] = torques

    def set_joint_impedance(self, command: ImpedanceCommand) -> None:
        command.validate(self.dofs)
        self._kp[:] = command.kp
        self._kd[:] = command.kd
        self._q_ref[:] = command.q_ref
        self._v_ref[:] = command.v_ref
        self._tau_ff[:] = command.tau_ff

    def _apply_torques(self) -> None:
        torque = self._tau_ff
        if self._kp.any() or self._kd.any():
            q, v = self._joint_states()
            torque = self._kp * (self._q_ref - q) + self._kd * (self._v_ref - v) + torque
        self._efforts = np.clip(torque, -self.effort_limits, self.effort_limits)
        self.client.setJointMotorControlArray(self.body, self._joints, self._pb.TORQUE_CONTROL, forces=list(self._efforts))
