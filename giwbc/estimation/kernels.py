"""Compiled kernels of the state estimator's per-tick update (issue 37): leg kinematics and the leg
Kalman filter, each one call over plain float64 arrays instead of dozens of Pinocchio and numpy calls.

Why compiled: a tick of the estimator is a few hundred floating-point operations spread over ~60
calls of about a microsecond each (Pinocchio's passes were 7 of the kinematics' 25 µs, the rest
numpy glue on 3- to 18-vectors; the Kalman update, 4 x 4 matrices, 40 µs). Compiled with numba, a
kernel costs its dispatch (~0.1 µs an argument) and its arithmetic.

Each kernel is a plain Python function compiled by :func:`giwbc.util.jit.compiled` (numba,
``cache=True``, no ``fastmath``); ``reference(kernel)`` is the same function uncompiled (what the
tests compare the compiled one with). Results differ from the previous numpy/LAPACK implementation
by rounding only (their own sums, their own LU in place of OpenBLAS's); a rollout stays bit for bit
reproducible on one machine.

Conventions: Pinocchio's (free-flyer ``q = [p, quat_xyzw, joints]``, ``v = [v_local, w_local,
joints]``; spatial vectors ``(linear, angular)``). The kinematics supports revolute and prismatic
joints (one coordinate each, any axis) below a free flyer: :func:`joint_tables` refuses others.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from giwbc.util.jit import compiled, reference

__all__ = [
    "assemble_state", "compensated_up", "compiled", "detect_contacts", "effort_forces", "joint_tables", "kalman_correct", "kalman_predict", "leg_accelerations",
    "leg_kinematics", "pivot_velocities", "pull_to_ground", "reference", "rolling_trust", "still_feet",
]

FREE_FLYER, REVOLUTE, PRISMATIC = 1, 2, 3
DYNAMICS, SOLVE, INERTIAL = 1, 2, 4  # leg_kinematics' mode bits: the RNEA bias, the feet's wrenches, the inertial term
_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


def joint_tables(model: pin.Model, frames: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tables :func:`leg_kinematics` reads, from a Pinocchio model whose joint 1 is a free flyer
    and whose other joints are revolute or prismatic, for the frames ``frames``:

    * ``joints_i`` (njoints, 4) int: parent, type (:data:`FREE_FLYER`, :data:`REVOLUTE`,
      :data:`PRISMATIC`), ``idx_q``, ``idx_v``;
    * ``joints_f`` (njoints, 29): axis (3, joint frame), placement in the parent joint's frame
      (rotation row by row, 9, then translation, 3), mass, centre of mass (3), rotational inertia
      about it (9), the joint's armature (reflected rotor inertia: ``armature * qdd`` in its torque);
    * ``frames_i`` (nframes,) int: each frame's parent joint; ``frames_f`` (nframes, 12): its
      placement in that joint's frame (rotation 9, translation 3);
    * ``support`` (nframes, njoints) bool: the joints between the universe and each frame."""
    n = model.njoints
    joints_i = np.zeros((n, 4), dtype=np.int64)
    joints_f = np.zeros((n, 29))
    for j in range(1, n):
        joint = model.joints[j]
        kind = joint.shortname()
        if j == 1:
            if kind != "JointModelFreeFlyer":
                raise NotImplementedError(f"leg kinematics kernel: joint 1 must be the free flyer, got {kind}")
            code, axis = FREE_FLYER, (0.0, 0.0, 0.0)
        elif kind.startswith(("JointModelR", "JointModelP")) and joint.nq == 1 and joint.nv == 1:
            code = REVOLUTE if kind.startswith("JointModelR") else PRISMATIC
            suffix = kind[len("JointModelR"):] if code == REVOLUTE else kind[len("JointModelP"):]
            if suffix in _AXES:
                axis = _AXES[suffix]
            elif suffix in ("evoluteUnaligned", "rismaticUnaligned"):
                axis = tuple(float(c) for c in np.asarray(joint.extract().axis, float))
            else:
                raise NotImplementedError(f"leg kinematics kernel: joint {model.names[j]!r} is a {kind}")
        else:
            raise NotImplementedError(f"leg kinematics kernel: joint {model.names[j]!r} is a {kind} (revolute and prismatic only)")
        placement, inertia = model.jointPlacements[j], model.inertias[j]
        joints_i[j] = (model.parents[j], code, joint.idx_q, joint.idx_v)
        joints_f[j, 0:3] = axis
        joints_f[j, 3:12] = placement.rotation.reshape(-1)
        joints_f[j, 12:15] = placement.translation
        joints_f[j, 15] = inertia.mass
        joints_f[j, 16:19] = inertia.lever
        joints_f[j, 19:28] = np.asarray(inertia.inertia).reshape(-1)
        if code != FREE_FLYER:
            joints_f[j, 28] = model.armature[joint.idx_v]
    frames_i = np.array([model.frames[f].parentJoint for f in frames], dtype=np.int64)
    frames_f = np.array([np.concatenate([model.frames[f].placement.rotation.reshape(-1), model.frames[f].placement.translation])
                         for f in frames])
    support = np.zeros((len(frames), n), dtype=np.bool_)
    for k, joint in enumerate(frames_i):
        support[k, list(model.supports[int(joint)])] = True
    support[:, 0] = False
    return joints_i, joints_f, frames_i, frames_f, support


@compiled
def leg_kinematics(
    joints_i: np.ndarray, joints_f: np.ndarray, frames_i: np.ndarray, frames_f: np.ndarray, support: np.ndarray,
    gravity: np.ndarray, leg_columns: np.ndarray, index: np.ndarray, q: np.ndarray, v: np.ndarray, a: np.ndarray,
    positions: np.ndarray, velocities: np.ndarray, efforts: np.ndarray, joint_accelerations: np.ndarray, mode: int,
    jacobians: np.ndarray, frame_motion: np.ndarray, relative_motion: np.ndarray, rotations: np.ndarray,
    angular_velocities: np.ndarray, bias: np.ndarray, wrenches: np.ndarray,
) -> int:
    """One update of :class:`~giwbc.estimation.kinematics.LegKinematics`: forward kinematics of the
    frames (the feet, then the IMU), their LOCAL_WORLD_ALIGNED Jacobians and velocities, and with
    the :data:`DYNAMICS` bit of ``mode`` the legs' inverse dynamics (RNEA, Featherstone's recursion
    in joint frames) less the joint ``efforts``: ``bias``, with :data:`SOLVE` too the feet's wrenches
    from it (each leg's ``J_leg^T w = bias``, 6 x 6 LU with partial pivoting).

    ``q``/``v``/``a``: the model's configuration, velocity and acceleration with the base part
    already set (``q[3:7]``, ``v[3:6]``, ``a[:6]``); the joint parts are gathered here from the
    description-order ``positions``/``velocities``/``joint_accelerations`` through ``index``
    (model joint k <- description joint ``index[k]``; ``a``'s only with the :data:`INERTIAL` bit,
    else ``a`` is used as it is). ``leg_columns`` (n_feet, 6): each foot's leg's velocity columns
    (:data:`SOLVE`).
    Returns 0, or 1 + the first foot whose leg Jacobian is singular (its wrench left as it was)."""
    n_joints, n_frames, nv = joints_i.shape[0], frames_i.shape[0], v.shape[0]
    n_feet = n_frames - 1
    for k in range(index.shape[0]):
        q[7 + k] = positions[index[k]]
        v[6 + k] = velocities[index[k]]
        if mode & INERTIAL:
            a[6 + k] = joint_accelerations[index[k]]
    # forward pass: placements in the parent (lR, lp), in the world (oR, op), and the RNEA's motions
    lR = np.zeros((n_joints, 3, 3))
    lp = np.zeros((n_joints, 3))
    oR = np.zeros((n_joints, 3, 3))
    op = np.zeros((n_joints, 3))
    vel = np.zeros((n_joints, 6))
    acc = np.zeros((n_joints, 6))
    force = np.zeros((n_joints, 6))
    vj = np.zeros(6)
    oR[0, 0, 0] = oR[0, 1, 1] = oR[0, 2, 2] = 1.0
    acc[0, 0], acc[0, 1], acc[0, 2] = -gravity[0], -gravity[1], -gravity[2]  # gravity as the universe's acceleration
    for i in range(1, n_joints):
        parent, kind, iq, iv = joints_i[i, 0], joints_i[i, 1], joints_i[i, 2], joints_i[i, 3]
        f = joints_f[i]
        ux, uy, uz = f[0], f[1], f[2]
        if kind == FREE_FLYER:
            x, y, z, w = q[iq + 3], q[iq + 4], q[iq + 5], q[iq + 6]
            lR[i, 0, 0] = 1.0 - 2.0 * (y * y + z * z)
            lR[i, 0, 1] = 2.0 * (x * y - z * w)
            lR[i, 0, 2] = 2.0 * (x * z + y * w)
            lR[i, 1, 0] = 2.0 * (x * y + z * w)
            lR[i, 1, 1] = 1.0 - 2.0 * (x * x + z * z)
            lR[i, 1, 2] = 2.0 * (y * z - x * w)
            lR[i, 2, 0] = 2.0 * (x * z - y * w)
            lR[i, 2, 1] = 2.0 * (y * z + x * w)
            lR[i, 2, 2] = 1.0 - 2.0 * (x * x + y * y)
            for r in range(3):
                lp[i, r] = q[iq + r]
            for r in range(6):
                vj[r] = v[iv + r]
        else:
            angle = q[iq]
            rate = v[iv]
            if kind == REVOLUTE:  # R(axis, angle) by Rodrigues' formula, after the joint's placement
                c, s = np.cos(angle), np.sin(angle)
                t = 1.0 - c
                m00, m01, m02 = c + t * ux * ux, t * ux * uy - s * uz, t * ux * uz + s * uy
                m10, m11, m12 = t * ux * uy + s * uz, c + t * uy * uy, t * uy * uz - s * ux
                m20, m21, m22 = t * ux * uz - s * uy, t * uy * uz + s * ux, c + t * uz * uz
                for r in range(3):
                    p0, p1, p2 = f[3 + 3 * r], f[4 + 3 * r], f[5 + 3 * r]
                    lR[i, r, 0] = p0 * m00 + p1 * m10 + p2 * m20
                    lR[i, r, 1] = p0 * m01 + p1 * m11 + p2 * m21
                    lR[i, r, 2] = p0 * m02 + p1 * m12 + p2 * m22
                    lp[i, r] = f[12 + r]
                vj[0] = vj[1] = vj[2] = 0.0
                vj[3], vj[4], vj[5] = ux * rate, uy * rate, uz * rate
            else:  # PRISMATIC: a translation along the axis, after the joint's placement
                for r in range(3):
                    lR[i, r, 0], lR[i, r, 1], lR[i, r, 2] = f[3 + 3 * r], f[4 + 3 * r], f[5 + 3 * r]
                    lp[i, r] = f[12 + r] + angle * (f[3 + 3 * r] * ux + f[4 + 3 * r] * uy + f[5 + 3 * r] * uz)
                vj[0], vj[1], vj[2] = ux * rate, uy * rate, uz * rate
                vj[3] = vj[4] = vj[5] = 0.0
        for r in range(3):
            for col in range(3):
                oR[i, r, col] = oR[parent, r, 0] * lR[i, 0, col] + oR[parent, r, 1] * lR[i, 1, col] + oR[parent, r, 2] * lR[i, 2, col]
            op[i, r] = op[parent, r] + oR[parent, r, 0] * lp[i, 0] + oR[parent, r, 1] * lp[i, 1] + oR[parent, r, 2] * lp[i, 2]
        if not mode & DYNAMICS:
            continue
        # v_i = X^-1 v_parent + v_J; a_i = X^-1 a_parent + S qdd + v_i x v_J (motions (linear, angular), joint frames)
        tx, ty, tz = lp[i, 0], lp[i, 1], lp[i, 2]
        for target, source in ((vel, vel), (acc, acc)):
            lx, ly, lz = source[parent, 0], source[parent, 1], source[parent, 2]
            wx, wy, wz = source[parent, 3], source[parent, 4], source[parent, 5]
            lx, ly, lz = lx + wy * tz - wz * ty, ly + wz * tx - wx * tz, lz + wx * ty - wy * tx  # v + w x t
            for col in range(3):
                target[i, col] = lR[i, 0, col] * lx + lR[i, 1, col] * ly + lR[i, 2, col] * lz
                target[i, 3 + col] = lR[i, 0, col] * wx + lR[i, 1, col] * wy + lR[i, 2, col] * wz
        for r in range(6):
            vel[i, r] += vj[r]
        if kind == FREE_FLYER:
            for r in range(6):
                acc[i, r] += a[iv + r]
        elif kind == REVOLUTE:
            acc[i, 3] += ux * a[iv]
            acc[i, 4] += uy * a[iv]
            acc[i, 5] += uz * a[iv]
        else:
            acc[i, 0] += ux * a[iv]
            acc[i, 1] += uy * a[iv]
            acc[i, 2] += uz * a[iv]
        lx, ly, lz, wx, wy, wz = vel[i, 0], vel[i, 1], vel[i, 2], vel[i, 3], vel[i, 4], vel[i, 5]
        jx, jy, jz, kx, ky, kz = vj[0], vj[1], vj[2], vj[3], vj[4], vj[5]
        acc[i, 0] += wy * jz - wz * jy + ly * kz - lz * ky  # (v, w) x (vJ, wJ) = (w x vJ + v x wJ, w x wJ)
        acc[i, 1] += wz * jx - wx * jz + lz * kx - lx * kz
        acc[i, 2] += wx * jy - wy * jx + lx * ky - ly * kx
        acc[i, 3] += wy * kz - wz * ky
        acc[i, 4] += wz * kx - wx * kz
        acc[i, 5] += wx * ky - wy * kx
        # f_i = I a_i + v_i x* (I v_i); I (v, w) = (m (v - c x w), I_c w + c x m (v - c x w))
        mass, cx, cy, cz = f[15], f[16], f[17], f[18]
        for k in range(2):
            src = acc if k == 0 else vel
            sx, sy, sz, ox, oy, oz = src[i, 0], src[i, 1], src[i, 2], src[i, 3], src[i, 4], src[i, 5]
            hx = mass * (sx - (cy * oz - cz * oy))
            hy = mass * (sy - (cz * ox - cx * oz))
            hz = mass * (sz - (cx * oy - cy * ox))
            nx = f[19] * ox + f[20] * oy + f[21] * oz + (cy * hz - cz * hy)
            ny = f[22] * ox + f[23] * oy + f[24] * oz + (cz * hx - cx * hz)
            nz = f[25] * ox + f[26] * oy + f[27] * oz + (cx * hy - cy * hx)
            if k == 0:
                force[i, 0], force[i, 1], force[i, 2], force[i, 3], force[i, 4], force[i, 5] = hx, hy, hz, nx, ny, nz
            else:  # (v, w) x* (h, n) = (w x h, w x n + v x h)
                force[i, 0] += wy * hz - wz * hy
                force[i, 1] += wz * hx - wx * hz
                force[i, 2] += wx * hy - wy * hx
                force[i, 3] += wy * nz - wz * ny + ly * hz - lz * hy
                force[i, 4] += wz * nx - wx * nz + lz * hx - lx * hz
                force[i, 5] += wx * ny - wy * nx + lx * hy - ly * hx
    # frames: placements, Jacobians (LOCAL_WORLD_ALIGNED) and velocities
    jacobians[:] = 0.0
    for k in range(n_frames):
        j = frames_i[k]
        g = frames_f[k]
        px = op[j, 0] + oR[j, 0, 0] * g[9] + oR[j, 0, 1] * g[10] + oR[j, 0, 2] * g[11]
        py = op[j, 1] + oR[j, 1, 0] * g[9] + oR[j, 1, 1] * g[10] + oR[j, 1, 2] * g[11]
        pz = op[j, 2] + oR[j, 2, 0] * g[9] + oR[j, 2, 1] * g[10] + oR[j, 2, 2] * g[11]
        frame_motion[k, 0], frame_motion[k, 1], frame_motion[k, 2] = px, py, pz
        if k < n_feet:
            for r in range(3):
                for col in range(3):
                    rotations[k, r, col] = oR[j, r, 0] * g[col] + oR[j, r, 1] * g[3 + col] + oR[j, r, 2] * g[6 + col]
        jac = jacobians[k]
        for i in range(1, n_joints):
            if not support[k, i]:
                continue
            kind, iv = joints_i[i, 1], joints_i[i, 3]
            dx, dy, dz = px - op[i, 0], py - op[i, 1], pz - op[i, 2]
            if kind == FREE_FLYER:
                for col in range(3):
                    ax, ay, az = oR[i, 0, col], oR[i, 1, col], oR[i, 2, col]
                    jac[0, iv + col], jac[1, iv + col], jac[2, iv + col] = ax, ay, az
                    jac[0, iv + 3 + col] = ay * dz - az * dy
                    jac[1, iv + 3 + col] = az * dx - ax * dz
                    jac[2, iv + 3 + col] = ax * dy - ay * dx
                    jac[3, iv + 3 + col], jac[4, iv + 3 + col], jac[5, iv + 3 + col] = ax, ay, az
                continue
            f = joints_f[i]
            ax = oR[i, 0, 0] * f[0] + oR[i, 0, 1] * f[1] + oR[i, 0, 2] * f[2]
            ay = oR[i, 1, 0] * f[0] + oR[i, 1, 1] * f[1] + oR[i, 1, 2] * f[2]
            az = oR[i, 2, 0] * f[0] + oR[i, 2, 1] * f[1] + oR[i, 2, 2] * f[2]
            if kind == REVOLUTE:
                jac[0, iv], jac[1, iv], jac[2, iv] = ay * dz - az * dy, az * dx - ax * dz, ax * dy - ay * dx
                jac[3, iv], jac[4, iv], jac[5, iv] = ax, ay, az
            else:
                jac[0, iv], jac[1, iv], jac[2, iv] = ax, ay, az
        for r in range(3):
            linear = 0.0
            angular = 0.0
            for col in range(nv):
                linear += jac[r, col] * v[col]
                angular += jac[3 + r, col] * v[col]
            frame_motion[k, 3 + r] = linear
            if k < n_feet:
                angular_velocities[k, r] = angular
    for k in range(n_feet):
        for r in range(6):
            relative_motion[k, r] = frame_motion[k, r] - frame_motion[n_feet, r]
    if not mode & DYNAMICS:
        return 0
    # backward pass: joint torques, each body's force carried to its parent
    for i in range(n_joints - 1, 0, -1):
        parent, kind, iv = joints_i[i, 0], joints_i[i, 1], joints_i[i, 3]
        f = joints_f[i]
        if kind == FREE_FLYER:
            continue  # the base's wrench is not needed (only the joints' torques)
        if kind == REVOLUTE:
            tau = f[0] * force[i, 3] + f[1] * force[i, 4] + f[2] * force[i, 5]
        else:
            tau = f[0] * force[i, 0] + f[1] * force[i, 1] + f[2] * force[i, 2]
        tau += f[28] * a[iv]  # the rotor's inertia (Pinocchio's armature)
        bias[iv - 6] = tau - efforts[index[iv - 6]]
        if parent > 1:  # the base's own wrench is never read
            hx = lR[i, 0, 0] * force[i, 0] + lR[i, 0, 1] * force[i, 1] + lR[i, 0, 2] * force[i, 2]
            hy = lR[i, 1, 0] * force[i, 0] + lR[i, 1, 1] * force[i, 1] + lR[i, 1, 2] * force[i, 2]
            hz = lR[i, 2, 0] * force[i, 0] + lR[i, 2, 1] * force[i, 1] + lR[i, 2, 2] * force[i, 2]
            nx = lR[i, 0, 0] * force[i, 3] + lR[i, 0, 1] * force[i, 4] + lR[i, 0, 2] * force[i, 5]
            ny = lR[i, 1, 0] * force[i, 3] + lR[i, 1, 1] * force[i, 4] + lR[i, 1, 2] * force[i, 5]
            nz = lR[i, 2, 0] * force[i, 3] + lR[i, 2, 1] * force[i, 4] + lR[i, 2, 2] * force[i, 5]
            tx, ty, tz = lp[i, 0], lp[i, 1], lp[i, 2]
            force[parent, 0] += hx
            force[parent, 1] += hy
            force[parent, 2] += hz
            force[parent, 3] += nx + ty * hz - tz * hy
            force[parent, 4] += ny + tz * hx - tx * hz
            force[parent, 5] += nz + tx * hy - ty * hx
    if not mode & SOLVE:
        return 0
    # each leg's J_leg^T w = bias: 6 x 6, LU with partial pivoting
    system = np.empty((6, 7))
    for foot in range(n_feet):
        for r in range(6):
            column = leg_columns[foot, r]
            for col in range(6):
                system[r, col] = jacobians[foot, col, column]
            system[r, 6] = bias[column - 6]
        for col in range(6):
            pivot, best = col, abs(system[col, col])
            for r in range(col + 1, 6):
                if abs(system[r, col]) > best:
                    pivot, best = r, abs(system[r, col])
            if best == 0.0:
                return foot + 1
            if pivot != col:
                for c in range(col, 7):
                    system[col, c], system[pivot, c] = system[pivot, c], system[col, c]
            for r in range(col + 1, 6):
                factor = system[r, col] / system[col, col]
                if factor != 0.0:
                    for c in range(col + 1, 7):
                        system[r, c] -= factor * system[col, c]
        for r in range(5, -1, -1):
            total = system[r, 6]
            for c in range(r + 1, 6):
                total -= system[r, c] * wrenches[foot, c]
            wrenches[foot, r] = total / system[r, r]
    return 0


@compiled
def kalman_predict(
    x: np.ndarray, P: np.ndarray, acceleration: np.ndarray, known: bool, dt: float, stance: np.ndarray, noise: np.ndarray
) -> None:
    """:meth:`~giwbc.estimation.kalman.LegKalmanFilter.predict` on its arrays: ``x`` (3, states)
    and the axis groups' covariances ``P`` (groups, states, states) in place. ``noise``: the
    standard deviations (acceleration, missing acceleration, position, stance foot, swing foot);
    ``known``: whether ``acceleration`` (world) is the IMU's (else 0, with the missing noise)."""
    half_dt2 = 0.5 * dt * dt
    for axis in range(3):
        accel = acceleration[axis] if known else 0.0
        position, velocity = x[axis, 0], x[axis, 1]
        x[axis, 0] = position + (velocity * dt + half_dt2 * accel)
        x[axis, 1] = velocity + accel * dt
    acceleration_std = noise[0] if known else noise[1]
    states = P.shape[1]
    process = np.empty(states)
    process[0] = noise[2] * noise[2] * dt
    process[1] = acceleration_std * acceleration_std * dt
    for i in range(states - 2):
        std = min(noise[3] / max(stance[i], 1e-6), noise[4])
        process[2 + i] = std * std * dt
    for g in range(P.shape[0]):
        for col in range(states):  # F P F^T, F = I + dt e_0 e_1^T: a row, then a column operation
            P[g, 0, col] += dt * P[g, 1, col]
        for r in range(states):
            P[g, r, 0] += dt * P[g, r, 1]
        for r in range(states):
            P[g, r, r] += process[r]


@compiled
def kalman_correct(
    x: np.ndarray, P: np.ndarray, H_full: np.ndarray, group_rows: np.ndarray, group_axes: np.ndarray, z: np.ndarray,
    used: np.ndarray, variances: np.ndarray, confidences: np.ndarray, foot_positions: np.ndarray, foot_velocities: np.ndarray,
    position_valid: np.ndarray, velocity_valid: np.ndarray, ground_height: float, velocity_noise: float, gate: float,
    power: float, corrections: int,
) -> int:
    """:meth:`~giwbc.estimation.kalman.LegKalmanFilter.correct` on its arrays, in place: the
    measurements ``z`` (per axis: the feet's positions, velocities, then, with ground rows, the
    ``ground_height``) and which rows are ``used`` (a valid position; a valid velocity or a ground
    height of a stance foot, ``confidences`` > 0), the stance feet's velocity noise
    (``variances[n:2n]``: encoder noise over the squared confidence, grown beyond the chi-square
    ``gate``), then per axis group ``g`` (its axes ``group_axes[g]``, its first ``group_rows[g]``
    rows of ``H_full[g]``, those not used zeroed) the Kalman update ``K^T = S^-1 H P``,
    ``x += (z - H x) K^T``, ``P -= K H P``, every 16th correction (``corrections`` + 1) followed by
    symmetrizing ``P``. Returns the new correction count, or -1 when an innovation covariance is
    singular (nothing after it updated)."""
    n = confidences.shape[0]
    groups, states = P.shape[0], P.shape[1]
    for i in range(n):
        stance = confidences[i] > 0.0
        used[i] = position_valid[i]
        used[n + i] = stance and velocity_valid[i]
        if z.shape[1] > 2 * n:
            used[2 * n + i] = stance and position_valid[i]
            z[2, 2 * n + i] = ground_height
        for axis in range(3):
            z[axis, i] = foot_positions[i, axis]
            z[axis, n + i] = foot_velocities[i, axis]
    # the velocity rows' noise: each axis's IMU velocity variance from its group's P
    axis_variance = np.empty(3)
    for g in range(groups):
        for axis in range(group_axes[g, 0], group_axes[g, 1]):
            axis_variance[axis] = P[g, 1, 1]
    for i in range(n):
        confidence = max(confidences[i], 1e-3)
        variance = velocity_noise / (confidence * confidence)
        if gate > 0:
            rx, ry, rz = foot_velocities[i, 0] + x[0, 1], foot_velocities[i, 1] + x[1, 1], foot_velocities[i, 2] + x[2, 1]
            nis = rx * rx / (axis_variance[0] + variance) + ry * ry / (axis_variance[1] + variance) + rz * rz / (axis_variance[2] + variance)
            if nis > gate:
                variance *= nis / gate if power == 1.0 else (nis / gate) ** power
        variances[n + i] = variance
    rows_max = H_full.shape[1]
    H = np.empty((rows_max, states))
    HP = np.empty((rows_max, states))
    S = np.empty((rows_max, rows_max))
    gain = np.empty((rows_max, states))  # K^T
    residual = np.empty(rows_max)
    for g in range(groups):
        rows = group_rows[g]
        for r in range(rows):
            for c in range(states):
                H[r, c] = H_full[g, r, c] if used[r] else 0.0
        for r in range(rows):
            for c in range(states):
                total = 0.0
                for k in range(states):
                    total += H[r, k] * P[g, k, c]
                HP[r, c] = total
        for r in range(rows):
            for c in range(rows):
                total = 0.0
                for k in range(states):
                    total += HP[r, k] * H[c, k]
                S[r, c] = total
            S[r, r] += variances[r]
        # K^T = S^-1 HP: LU with partial pivoting on S, HP's columns the right-hand sides
        for r in range(rows):
            for c in range(states):
                gain[r, c] = HP[r, c]
        for col in range(rows):
            pivot, best = col, abs(S[col, col])
            for r in range(col + 1, rows):
                if abs(S[r, col]) > best:
                    pivot, best = r, abs(S[r, col])
            if best == 0.0:
                return -1
            if pivot != col:
                for c in range(rows):
                    S[col, c], S[pivot, c] = S[pivot, c], S[col, c]
                for c in range(states):
                    gain[col, c], gain[pivot, c] = gain[pivot, c], gain[col, c]
            for r in range(col + 1, rows):
                factor = S[r, col] / S[col, col]
                if factor != 0.0:
                    for c in range(col + 1, rows):
                        S[r, c] -= factor * S[col, c]
                    for c in range(states):
                        gain[r, c] -= factor * gain[col, c]
        for r in range(rows - 1, -1, -1):
            for c in range(states):
                total = gain[r, c]
                for k in range(r + 1, rows):
                    total -= S[r, k] * gain[k, c]
                gain[r, c] = total / S[r, r]
        for axis in range(group_axes[g, 0], group_axes[g, 1]):
            for r in range(rows):
                predicted = 0.0
                for c in range(states):
                    predicted += H[r, c] * x[axis, c]
                residual[r] = (z[axis, r] if used[r] else 0.0) - predicted
            for c in range(states):
                total = 0.0
                for r in range(rows):
                    total += residual[r] * gain[r, c]
                x[axis, c] += total
        for r in range(states):
            for c in range(states):
                total = 0.0
                for k in range(rows):
                    total += gain[k, r] * HP[k, c]
                P[g, r, c] -= total
    corrections += 1
    if corrections % 16 == 0:  # keep P symmetric against rounding
        for g in range(groups):
            for r in range(states):
                for c in range(r + 1, states):
                    mean = 0.5 * (P[g, r, c] + P[g, c, r])
                    P[g, r, c] = mean
                    P[g, c, r] = mean
    return corrections


@compiled
def pivot_velocities(
    wrenches: np.ndarray, rotations: np.ndarray, angular_velocities: np.ndarray, velocities: np.ndarray, half_sizes: np.ndarray,
    out: np.ndarray,
) -> None:
    """Per foot, the velocity of its centre of pressure (``v_centre + w_foot x r``, ``r`` the CoP from
    the sole centre on the sole plane, from the wrench ``(force, torque)`` at the sole centre, clamped
    to the sole's ``half_sizes`` (length, width)) into ``out``; a foot whose force along its sole
    normal is not positive keeps its centre's velocity. All world axes; ``rotations``: the soles'."""
    for i in range(wrenches.shape[0]):
        fx, fy, fz, tx, ty, tz = wrenches[i, 0], wrenches[i, 1], wrenches[i, 2], wrenches[i, 3], wrenches[i, 4], wrenches[i, 5]
        m = rotations[i]
        vx, vy, vz = velocities[i, 0], velocities[i, 1], velocities[i, 2]
        normal = m[0, 2] * fx + m[1, 2] * fy + m[2, 2] * fz  # force along the sole normal
        if normal <= 1e-6:
            out[i, 0], out[i, 1], out[i, 2] = vx, vy, vz
            continue
        sx, sy = m[0, 0] * tx + m[1, 0] * ty + m[2, 0] * tz, m[0, 1] * tx + m[1, 1] * ty + m[2, 1] * tz  # torque, sole frame
        half_length, half_width = half_sizes[i, 0], half_sizes[i, 1]
        px = min(max(-sy / normal, -half_length), half_length)
        py = min(max(sx / normal, -half_width), half_width)
        rx, ry, rz = m[0, 0] * px + m[0, 1] * py, m[1, 0] * px + m[1, 1] * py, m[2, 0] * px + m[2, 1] * py  # world axes
        wx, wy, wz = angular_velocities[i, 0], angular_velocities[i, 1], angular_velocities[i, 2]
        out[i, 0] = vx + wy * rz - wz * ry
        out[i, 1] = vy + wz * rx - wx * rz
        out[i, 2] = vz + wx * ry - wy * rx


@compiled
def leg_accelerations(
    velocities: np.ndarray, joint_lp: np.ndarray, joint_accelerations: np.ndarray, base_lp: np.ndarray, restart_joints: bool,
    restart_base: bool, omega: tuple, accel: tuple, has_accel: bool, rotation: tuple, imu_rotation: tuple, imu_offset: tuple,
    gravity: tuple, alpha: float, rate: float, out: np.ndarray,
) -> None:
    """The state estimator's ``force_inertia`` accelerations, in place: the joints' (``joint_lp``, the
    joint ``velocities`` low-passed by ``alpha``, and ``joint_accelerations``, its derivative: the
    change times ``rate``; ``restart_joints``: ``joint_lp`` starts at ``velocities``) and the base's
    into ``out`` (base frame: the origin's linear acceleration without gravity, then the angular
    one): ``base_lp`` low-passes the base angular velocity ``omega`` (base frame) and the IMU's
    world acceleration (the bias-free specific force ``accel`` rotated by ``imu_rotation`` then
    ``rotation``, both 3 x 3 row by row, plus ``gravity``; 0 without ``has_accel``), the angular
    acceleration is the angular velocity's change times ``rate``, and the IMU's acceleration moves
    to the base origin by the lever terms ``alpha x r + w x (w x r)`` (``r``: ``imu_offset``, base
    frame). ``restart_base``: the low-pass starts here (no derivative: zero angular acceleration)."""
    if restart_joints:
        joint_lp[:] = velocities
    for k in range(velocities.shape[0]):
        change = velocities[k] - joint_lp[k]
        joint_lp[k] += alpha * change
        joint_accelerations[k] = change * rate
    m, i = rotation, imu_rotation
    if has_accel:
        sx, sy, sz = accel[0], accel[1], accel[2]
        bx, by, bz = i[0] * sx + i[1] * sy + i[2] * sz, i[3] * sx + i[4] * sy + i[5] * sz, i[6] * sx + i[7] * sy + i[8] * sz
        ax = m[0] * bx + m[1] * by + m[2] * bz + gravity[0]
        ay = m[3] * bx + m[4] * by + m[5] * bz + gravity[1]
        az = m[6] * bx + m[7] * by + m[8] * bz + gravity[2]
    else:
        ax = ay = az = 0.0
    wx, wy, wz = omega[0], omega[1], omega[2]
    if restart_base:
        base_lp[0], base_lp[1], base_lp[2], base_lp[3], base_lp[4], base_lp[5] = wx, wy, wz, ax, ay, az
        out[0] = m[0] * ax + m[3] * ay + m[6] * az
        out[1] = m[1] * ax + m[4] * ay + m[7] * az
        out[2] = m[2] * ax + m[5] * ay + m[8] * az
        out[3] = out[4] = out[5] = 0.0
        return
    dwx, dwy, dwz = wx - base_lp[0], wy - base_lp[1], wz - base_lp[2]
    base_lp[0] += alpha * (wx - base_lp[0])
    base_lp[1] += alpha * (wy - base_lp[1])
    base_lp[2] += alpha * (wz - base_lp[2])
    base_lp[3] += alpha * (ax - base_lp[3])
    base_lp[4] += alpha * (ay - base_lp[4])
    base_lp[5] += alpha * (az - base_lp[5])
    alpha_x, alpha_y, alpha_z = rate * dwx, rate * dwy, rate * dwz  # base angular acceleration, base frame
    px, py, pz = base_lp[3], base_lp[4], base_lp[5]
    lx, ly, lz = m[0] * px + m[3] * py + m[6] * pz, m[1] * px + m[4] * py + m[7] * pz, m[2] * px + m[5] * py + m[8] * pz
    rx, ry, rz = imu_offset[0], imu_offset[1], imu_offset[2]
    tx, ty, tz = alpha_y * rz - alpha_z * ry, alpha_z * rx - alpha_x * rz, alpha_x * ry - alpha_y * rx
    ox, oy, oz = base_lp[0], base_lp[1], base_lp[2]
    ux, uy, uz = oy * rz - oz * ry, oz * rx - ox * rz, ox * ry - oy * rx  # w x r
    cx, cy, cz = oy * uz - oz * uy, oz * ux - ox * uz, ox * uy - oy * ux  # w x (w x r)
    out[0], out[1], out[2] = lx - tx - cx, ly - ty - cy, lz - tz - cz
    out[3], out[4], out[5] = alpha_x, alpha_y, alpha_z


@compiled
def assemble_state(
    x: np.ndarray, imu_offset: np.ndarray, rotation: tuple, quaternion: tuple, omega_local: tuple, positions: np.ndarray,
    velocities: np.ndarray, q: np.ndarray, v: np.ndarray, state: np.ndarray,
) -> None:
    """The estimate's base state from the filter's IMU position and velocity (``x[:, 0]``,
    ``x[:, 1]``, world), the IMU's offset from the base origin (world axes), the base ``rotation``
    (3 x 3 row by row), ``quaternion`` (xyzw) and angular velocity ``omega_local`` (base frame):
    ``state`` = position, quaternion, linear velocity (the IMU's less ``w x offset``), angular
    velocity (world); and Pinocchio's ``q = [position, quaternion, positions]``, ``v = [R^T
    velocity, omega_local, velocities]``."""
    m = rotation
    lx, ly, lz = omega_local[0], omega_local[1], omega_local[2]
    wx, wy, wz = m[0] * lx + m[1] * ly + m[2] * lz, m[3] * lx + m[4] * ly + m[5] * lz, m[6] * lx + m[7] * ly + m[8] * lz
    ox, oy, oz = imu_offset[0], imu_offset[1], imu_offset[2]
    px, py, pz = x[0, 0] - ox, x[1, 0] - oy, x[2, 0] - oz
    vx, vy, vz = x[0, 1] - (wy * oz - wz * oy), x[1, 1] - (wz * ox - wx * oz), x[2, 1] - (wx * oy - wy * ox)
    state[0], state[1], state[2] = px, py, pz
    for k in range(4):
        state[3 + k] = quaternion[k]
        q[3 + k] = quaternion[k]
    state[7], state[8], state[9] = vx, vy, vz
    state[10], state[11], state[12] = wx, wy, wz
    q[0], q[1], q[2] = px, py, pz
    v[0] = m[0] * vx + m[3] * vy + m[6] * vz
    v[1] = m[1] * vx + m[4] * vy + m[7] * vz
    v[2] = m[2] * vx + m[5] * vy + m[8] * vz
    v[3], v[4], v[5] = lx, ly, lz
    for k in range(positions.shape[0]):
        q[7 + k] = positions[k]
        v[6 + k] = velocities[k]


@compiled
def compensated_up(
    accel: tuple, bias: tuple, rotation: tuple, imu_rotation: tuple, loads: tuple, foot_velocities: np.ndarray, x: np.ndarray,
    lp: np.ndarray, restart: bool, alpha: float, rate: float,
) -> tuple[float, float, float]:
    """The accelerometer's gravity (IMU frame) for the state estimator's gravity reference: the
    specific force ``accel`` less its ``bias``, rotated to the world (``imu_rotation`` then the base
    ``rotation``, 3 x 3 row by row), less the IMU's acceleration the stance legs measure: the IMU
    velocity ``-sum(load u) / sum(load)`` over the feet's relative velocities ``u`` (the filter's,
    ``x[:, 1]``, without a loaded foot) low-passed by ``alpha`` in ``lp[3:]`` and differentiated
    (its change times ``rate``), the specific force low-passed alike in ``lp[:3]`` (``restart``:
    both start here, no derivative)."""
    ax, ay, az = accel[0] - bias[0], accel[1] - bias[1], accel[2] - bias[2]
    i, m = imu_rotation, rotation
    bx, by, bz = i[0] * ax + i[1] * ay + i[2] * az, i[3] * ax + i[4] * ay + i[5] * az, i[6] * ax + i[7] * ay + i[8] * az
    fx, fy, fz = m[0] * bx + m[1] * by + m[2] * bz, m[3] * bx + m[4] * by + m[5] * bz, m[6] * bx + m[7] * by + m[8] * bz
    total = 0.0
    for k in range(len(loads)):
        total += loads[k]
    if total > 0.0:
        vx = vy = vz = 0.0
        for k in range(len(loads)):
            w = loads[k]
            vx -= w * foot_velocities[k, 0]
            vy -= w * foot_velocities[k, 1]
            vz -= w * foot_velocities[k, 2]  # a still stance foot: IMU velocity = -its relative velocity
        vx, vy, vz = vx / total, vy / total, vz / total
    else:
        vx, vy, vz = x[0, 1], x[1, 1], x[2, 1]
    if restart:
        lp[0], lp[1], lp[2], lp[3], lp[4], lp[5] = fx, fy, fz, vx, vy, vz
        mx, my, mz = fx, fy, fz
    else:
        dvx, dvy, dvz = vx - lp[3], vy - lp[4], vz - lp[5]
        lp[3] += alpha * dvx
        lp[4] += alpha * dvy
        lp[5] += alpha * dvz
        lp[0] += alpha * (fx - lp[0])
        lp[1] += alpha * (fy - lp[1])
        lp[2] += alpha * (fz - lp[2])
        mx, my, mz = lp[0] - rate * dvx, lp[1] - rate * dvy, lp[2] - rate * dvz
    wx, wy, wz = m[0] * mx + m[3] * my + m[6] * mz, m[1] * mx + m[4] * my + m[7] * mz, m[2] * mx + m[5] * my + m[8] * mz
    return (i[0] * wx + i[3] * wy + i[6] * wz, i[1] * wx + i[4] * wy + i[7] * wz, i[2] * wx + i[5] * wy + i[8] * wz)


@compiled
def pull_to_ground(x: np.ndarray, flags: tuple, still: tuple, ground: float, step: float) -> None:
    """The state estimator's ``ground_pull``: the filter's height states ``x[2]`` (the IMU's and
    every foot's; not the velocity) shifted together toward ``ground`` by the stance feet
    (``flags``), each weighted by ``still``, by the share ``min(step * min(weight, 1), 1)``
    (``step``: dt over the pull's time constant) of the weighted mean error."""
    error = weight = 0.0
    for k in range(len(flags)):
        if flags[k]:
            error += still[k] * (ground - x[2, 2 + k])
            weight += still[k]
    if weight > 0.0:
        shift = min(step * min(weight, 1.0), 1.0) * error / weight
        for k in range(x.shape[1]):
            if k != 1:  # the velocity is not a height
                x[2, k] += shift


@compiled
def effort_forces(
    wrenches: np.ndarray, valid: np.ndarray, foot_velocities: np.ndarray, x: np.ndarray, max_speed: float, pulling: bool,
    forces: np.ndarray,
) -> None:
    """The state estimator's effort-based ground forces (world) in place: each ``valid`` leg's
    wrench's force (the others keep theirs), then per foot: a negative normal force (a pull the
    ground cannot exert) reads 0 unless ``pulling``; with ``max_speed`` > 0 the force is scaled by
    the foot's standing share, 1 while its sole centre's world speed (the filter's IMU velocity
    ``x[:, 1]`` plus the foot's relative ``foot_velocities``) is at most half ``max_speed``, 0 from
    ``max_speed`` on, linear between."""
    for i in range(forces.shape[0]):
        if valid[i]:
            forces[i, 0], forces[i, 1], forces[i, 2] = wrenches[i, 0], wrenches[i, 1], wrenches[i, 2]
    for i in range(forces.shape[0]):
        if forces[i, 2] < 0.0 and not pulling:
            forces[i, 0] = forces[i, 1] = forces[i, 2] = 0.0
        elif max_speed > 0.0:
            sx, sy, sz = foot_velocities[i, 0] + x[0, 1], foot_velocities[i, 1] + x[1, 1], foot_velocities[i, 2] + x[2, 1]
            share = min(max(2.0 - 2.0 * math.sqrt(sx * sx + sy * sy + sz * sz) / max_speed, 0.0), 1.0)
            if share < 1.0:
                forces[i, 0] *= share
                forces[i, 1] *= share
                forces[i, 2] *= share


@compiled
def detect_contacts(
    measured: np.ndarray, usable: np.ndarray, filtered: np.ndarray, started: bool, alpha: float, on: float, off: float,
    previous: np.ndarray, contacts: np.ndarray,
) -> None:
    """:class:`~giwbc.estimation.contacts.ContactDetector`'s update: the ``measured`` normal forces
    low-passed into ``filtered`` by ``alpha`` (not ``started``: ``filtered`` starts at them, a
    non-finite one at 0; a foot not ``usable`` or whose step is not finite keeps its value), then
    per foot a Schmitt trigger from its ``previous`` flag into ``contacts``: on above ``on``, off
    below ``off`` (a foot not usable keeps its flag)."""
    for i in range(measured.shape[0]):
        force = measured[i]
        if not started:
            filtered[i] = force if math.isfinite(force) else 0.0
        else:
            step = alpha * (force - filtered[i])
            if usable[i] and math.isfinite(step):
                filtered[i] += step
        ok = usable[i]
        value = filtered[i]
        contacts[i] = (previous[i] or (ok and value > on)) and not (ok and value < off)


@compiled
def still_feet(
    angular_velocities: np.ndarray, loads: tuple, rate2: np.ndarray, since: np.ndarray, now: float, alpha: float, scale: float,
    least: float, out: np.ndarray,
) -> None:
    """The state estimator's stance confidences less for a turning foot (``foot_roll_rate``): each
    sole's squared angular rate low-passed into ``rate2`` by ``alpha`` (a non-finite one skipped),
    ``turning`` = that times ``scale`` (1 / foot_roll_rate^2); a foot turning (``turning`` > 1) is
    still from ``now`` at the earliest (``since``); into ``out``: ``max(load / (1 + turning),
    least)`` for a loaded foot, 0 for the others."""
    for i in range(rate2.shape[0]):
        wx, wy, wz = angular_velocities[i, 0], angular_velocities[i, 1], angular_velocities[i, 2]
        w2 = wx * wx + wy * wy + wz * wz
        if math.isfinite(w2):
            rate2[i] += alpha * (w2 - rate2[i])
        turning = rate2[i] * scale
        if turning > 1.0:
            since[i] = now
        load = loads[i]
        out[i] = max(load / (1.0 + turning), least) if load > 0.0 else 0.0


@compiled
def rolling_trust(angular_velocities: np.ndarray, loads: tuple, rate2: np.ndarray, alpha: float, scale: float, out: np.ndarray) -> None:
    """The state estimator's ``roll_velocity_rate`` trust: each loaded foot's ``load`` over ``1 +
    rate^2 * scale`` (``scale``: 1 / roll_velocity_rate^2), ``rate^2`` the larger of the sole's
    squared angular rate now (the low-passed one when not finite) and low-passed (``rate2``, by
    ``alpha``), into ``out`` (0 for a foot not loaded)."""
    for i in range(rate2.shape[0]):
        wx, wy, wz = angular_velocities[i, 0], angular_velocities[i, 1], angular_velocities[i, 2]
        w2 = wx * wx + wy * wy + wz * wz
        if not math.isfinite(w2):
            w2 = rate2[i]
        rate2[i] += alpha * (w2 - rate2[i])
        load = loads[i]
        out[i] = load / (1.0 + max(w2, rate2[i]) * scale) if load > 0.0 else 0.0
