"""Footstep planning from a velocity command ``(vx, vy, yaw_rate)`` (body frame, m/s and rad/s).

Feet alternate. Every step advances the body by ``vx · T`` along the stance foot's heading
(``T`` = single + double support); lateral motion and turning are done by the *leading* foot
(the one on the side of the motion), which steps out by ``2 |vy| T`` and turns by
``2 |yaw_rate| T``, the other foot following back to the nominal width and the new heading —
so feet never cross nor narrow below the nominal width, and the averages are the command.

Limits (:class:`GaitConfig`): step length forward and backward, extra lateral width, yaw per
step, minimum width. Beyond the velocities these allow at the base timing, the gait's
:class:`GaitEnvelope` takes over (:meth:`GaitConfig.for_command`): faster cadence (shorter single
and double support) and the envelope's step limits (longer backward steps, more turned ones),
interpolated from the base gait at its limits to the envelope's gait at the envelope's edge — a
command inside the base limits gets the base gait, unchanged. A command beyond the envelope is
*clamped* (the notes say which and by how much; beside a widened component the others shrink,
:attr:`GaitEnvelope.combined`; backward while turning is bounded, :attr:`GaitConfig.backward_turning`);
a non-finite command is *refused* with ``ValueError``.

A turning plan is *compensated* (:meth:`FootstepPlanner.turn_compensated`): the (vx, vy) it plans
with are those whose steps' cycle, seen in the feet's mean heading, goes at the command's — each
step goes along its stance sole's heading and the feet turn about a sole, which alone would walk
(0.5, 0, 0.5) at (0.546, -0.057). A walker's velocity correction (:attr:`FootstepPlanner.correction`)
comes on top, and its drift correction (:attr:`FootstepPlanner.offset`: every landing moved along and
across the step's heading after the compensation, so a zero component is corrected too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from giwbc.locomotion.planar import rotate, rotate_back

SIDES = ("left", "right")
# FootstepPlanner.turn_compensated: fixed-point passes, and steps planned before the cycle measured.
TURN_COMPENSATION_ITERATIONS = 4
TURN_COMPENSATION_WARMUP = 4
CORRECTION_REACH = 0.04  # m a forward step may reach beyond max_step_forward while the velocity correction lengthens it


def side_sign(side: str) -> float:
    """+1 for the left foot, −1 for the right (the lateral direction of that foot)."""
    if side not in SIDES:
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    return 1.0 if side == "left" else -1.0


def other_side(side: str) -> str:
    if side == "left":  # (side_sign's check without its call when the side is valid: several times a walker tick)
        return "right"
    if side != "right":
        side_sign(side)  # raises, naming the side
    return "left"


def rotation2(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def wrap_angle(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class Footstep:
    """Where a sole lands: its centre on the ground (x, y) and heading ``yaw``."""

    side: str
    position: np.ndarray
    yaw: float = 0.0

    def __post_init__(self) -> None:
        side_sign(self.side)
        position = np.asarray(self.position, dtype=float).reshape(-1)[:2]
        if position.shape != (2,) or not (math.isfinite(position[0]) and math.isfinite(position[1]) and math.isfinite(self.yaw)):
            raise ValueError(f"footstep position and yaw must be finite, got {self.position}, {self.yaw}")
        object.__setattr__(self, "position", position)

    # (Plain floats: the same bits as ``rotation2(yaw).T @ (p − s)`` and ``s + rotation2(yaw) @ x``,
    # see giwbc.locomotion.planar, without numpy's per-call overhead on 2-vectors.)
    def to_local(self, point: np.ndarray) -> np.ndarray:
        """A world point (x, y) in this sole's frame."""
        position = self.position
        return np.array(rotate_back(math.cos(self.yaw), math.sin(self.yaw), float(point[0]) - float(position[0]), float(point[1]) - float(position[1])))

    def to_world(self, local: np.ndarray) -> np.ndarray:
        x, y = rotate(math.cos(self.yaw), math.sin(self.yaw), float(local[0]), float(local[1]))
        position = self.position
        return np.array([float(position[0]) + x, float(position[1]) + y])

    def relative(self, other: "Footstep") -> tuple[np.ndarray, float]:
        """``other``'s position in this sole's frame and its yaw relative to this one."""
        return self.to_local(other.position), wrap_angle(other.yaw - self.yaw)


@dataclass(frozen=True)
class VelocityCommand:
    vx: float = 0.0
    vy: float = 0.0
    yaw_rate: float = 0.0

    def __post_init__(self) -> None:
        values = (self.vx, self.vy, self.yaw_rate)
        if not all(isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(float(v)) for v in values):
            raise ValueError(f"velocity command (vx, vy, yaw_rate) must be finite numbers, got {values}")

    @property
    def is_zero(self) -> bool:
        return self.vx == 0.0 and self.vy == 0.0 and self.yaw_rate == 0.0


@dataclass(frozen=True)
class GaitEnvelope:
    """The velocities walked beyond the base gait's limits, and the gait at the envelope's edge.

    A command beyond the base gait's limits (:meth:`GaitConfig.base_limits`) walks with timing
    interpolated linearly from the base gait's (at its limits) to ``single_support`` /
    ``double_support`` here (at the envelope's edge), by the largest fraction of the way any
    component has gone; its steps may reach the ``max_step_*`` / ``max_extra_width`` here (the
    G1's leg reach). An edge at or below the base limit extends nothing.

    G1 defaults (MuJoCo, 12 s runs, tuning seed 1): at the edge cadence (0.28 + 0.07 s) the G1
    walks 0.5 m/s backward and turns 1.0 rad/s without a fall, its joints at least 0.09 rad inside
    their limits (at 0.4 m/s backward, between the base gait's cadence and the edge's, a joint went
    0.02-0.04 rad past its limit and the walk ran 0.36 m/s: README). Not sideways: beyond the base gait's 0.21 m/s (itself 0.002 rad from the ankle
    roll's limit) every cadence and step width tried (0.24-0.28 s single support, nominal width
    0.19-0.237 m, 0.26-0.4 m/s) took an ankle roll or a knee 0.05-0.08 rad past its limit. Not
    forward: every cadence and step length tried beyond the base gait (0.22-0.40 s single support,
    steps up to 0.6 m) reached 0.56-0.79 m/s at most, the step adapter shortening the steps to
    where the DCM goes (0.23 m at a nominal 0.38 m; the swing leg's momentum turns the CoM's
    acceleration against the DCM controller's) and the fastest cadences falling at 1.0 m/s."""

    forward: float = 0.6  # m/s (at or below the base gait's 0.609, GaitConfig.max_forward_speed: no extension)
    backward: float = 0.5  # m/s
    lateral: float = 0.2  # m/s (the base gait's 0.207: no extension)
    turning: float = 1.0  # rad/s
    single_support: float = 0.28  # s, at the envelope's edge
    double_support: float = 0.07  # s
    max_step_forward: float = 0.30  # m (the base gait's)
    max_step_backward: float = 0.22  # m
    max_extra_width: float = 0.19  # m (the base gait's)
    max_step_yaw: float = 0.95  # rad (the closed-loop heading turns ~0.87 rad per step at 1 rad/s)
    turn_about_centre: bool = True  # see GaitConfig.turn_about_centre
    # A command beyond the base limits in one component has the others within (1 − combined × its
    # envelope fraction) of their base limits: 40 % at the edge. (Fresh seeds 40000-40001 with the
    # full base limits beside the envelope: (0.5, −0.1, 0.8) fell, (−0.45, −0.2, 0) took a knee
    # 0.08 rad past its limit, (−0.3, 0, −0.9) walked 0.11 m/s backward.)
    combined: float = 0.6

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            if name == "turn_about_centre":
                continue
            if name == "combined":
                if not (0.0 <= self.combined <= 1.0):
                    raise ValueError(f"gait envelope combined must be in [0, 1], got {self.combined}")
                continue
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"gait envelope {name} must be finite and > 0, got {value}")


@dataclass(frozen=True)
class GaitConfig:
    """Timing and kinematic limits of the gait (G1 defaults)."""

    single_support: float = 0.36  # s
    double_support: float = 0.10  # s
    step_width: float = 0.237  # m, nominal lateral distance between sole centres
    min_width: float = 0.17  # m, never closer (no crossing)
    max_extra_width: float = 0.19  # m, how much wider than nominal a step may land
    max_step_forward: float = 0.30  # m, sole-to-sole along the stance heading (a standing recovery's too)
    # m/s (None: max_step_forward / step period): the forward edge walked. At 0.652 (0.30 m steps at the
    # base timing) the G1 walked 0.571-0.615 (fresh seeds 60000-60002, 20 s), at 0.609 0.599-0.603 (tuning
    # seeds 1-2). (Not by a shorter max_step_forward: 0.28 lost standing pushes forward, 25 N s forward-right.)
    max_forward_speed: float | None = 0.609
    max_step_backward: float = 0.15  # m
    max_step_yaw: float = 0.5  # rad, leading foot's turn per step
    max_inward_yaw: float = 0.05  # rad, a foot turned towards the other (toe collision)
    # Beyond the limits above (at this timing): faster cadence, longer steps (None: clamp at them).
    envelope: GaitEnvelope | None = field(default_factory=GaitEnvelope)
    # A turning step turns the feet about the point between them, not about the stance sole (which
    # walks the body forward by ~width × yaw rate / 2 while it turns: 0.12 m/s at 1 rad/s). The
    # envelope's gaits (GaitEnvelope.turn_about_centre); the base gait as it was.
    turn_about_centre: bool = False
    # Backward while turning (None: no bound): |vx| / its base limit + |yaw rate| / its base limit (at
    # most 1) within this. The G1 (tuning seed 1, 10 s): (-0.3, 0, 0.5) walked (-0.12, 0.03, 0.50) with
    # an ankle roll 0.10 rad past its limit, (-0.2, 0, 0.5) walked -0.14 and fell at 6.3 s; (-0.15, 0,
    # 0.3) (1.01) and (-0.3, 0, 0.15) (1.2) walked within 0.01 m/s of their vx, the joints inside their limits.
    backward_turning: float | None = 1.25

    def __post_init__(self) -> None:
        for name in ("single_support", "double_support", "step_width", "min_width", "max_step_forward", "max_step_backward", "max_step_yaw"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"gait {name} must be finite and > 0, got {value}")
        if self.max_forward_speed is not None and not (math.isfinite(self.max_forward_speed) and self.max_forward_speed > 0):
            raise ValueError(f"gait max_forward_speed must be finite and > 0 (or None), got {self.max_forward_speed}")
        if self.min_width > self.step_width:
            raise ValueError(f"min_width {self.min_width} exceeds the nominal step_width {self.step_width}")
        if self.envelope is not None:
            self._check_envelope(self.envelope)

    @property
    def step_period(self) -> float:
        return self.single_support + self.double_support

    def base_limits(self) -> dict[str, tuple[float, float]]:
        """The velocity ranges this timing and these step limits allow: ``{"vx": (lo, hi), "vy": …, "yaw_rate": …}``."""
        T = self.step_period
        vy = self.max_extra_width / (2.0 * T)
        yaw = self.max_step_yaw / (2.0 * T)
        forward = self.max_step_forward / T if self.max_forward_speed is None else min(self.max_step_forward / T, self.max_forward_speed)
        return {"vx": (-self.max_step_backward / T, forward), "vy": (-vy, vy), "yaw_rate": (-yaw, yaw)}

    def limits(self) -> dict[str, tuple[float, float]]:
        """The velocity ranges walked: the envelope's (at least the base limits), else the base limits."""
        base = self.base_limits()
        e = self.envelope
        if e is None:
            return base
        return {
            "vx": (min(base["vx"][0], -e.backward), max(base["vx"][1], e.forward)),
            "vy": (min(base["vy"][0], -e.lateral), max(base["vy"][1], e.lateral)),
            "yaw_rate": (min(base["yaw_rate"][0], -e.turning), max(base["yaw_rate"][1], e.turning)),
        }

    def envelope_fraction(self, command: VelocityCommand) -> float:
        """How far beyond the base limits ``command`` is, towards the envelope's edge: 0 inside the
        base limits, 1 at the edge (the largest fraction of any component)."""
        if self.envelope is None:
            return 0.0
        base, edge = self.base_limits(), self.limits()
        fraction = 0.0
        for name, value in (("vx", command.vx), ("vy", command.vy), ("yaw_rate", command.yaw_rate)):
            end = 1 if value > 0.0 else 0
            b, e = base[name][end], edge[name][end]
            if abs(value) > abs(b) and abs(e) > abs(b):
                fraction = max(fraction, min((abs(value) - abs(b)) / (abs(e) - abs(b)), 1.0))
        return fraction

    def for_command(self, command: VelocityCommand) -> GaitConfig:
        """The gait that walks ``command`` (inside :meth:`limits`): this one (the same object) inside
        the base limits; beyond them the cadence and step limits interpolated towards the envelope's
        (see :class:`GaitEnvelope`), as a gait without an envelope of its own."""
        fraction = self.envelope_fraction(command)
        if fraction == 0.0:
            return self
        return self._interpolated(fraction)

    def _interpolated(self, fraction: float) -> GaitConfig:
        e = self.envelope
        assert e is not None

        def towards(base: float, edge: float) -> float:
            return base + fraction * (edge - base)

        return replace(
            self, single_support=towards(self.single_support, e.single_support), double_support=towards(self.double_support, e.double_support),
            max_step_forward=max(self.max_step_forward, e.max_step_forward), max_step_backward=max(self.max_step_backward, e.max_step_backward),
            max_extra_width=max(self.max_extra_width, e.max_extra_width), max_step_yaw=max(self.max_step_yaw, e.max_step_yaw), envelope=None,
            turn_about_centre=e.turn_about_centre,
        )  # fmt: skip

    def _check_envelope(self, e: GaitEnvelope) -> None:
        """Every command in the envelope fits the interpolated gait's step limits (one line if not)."""
        base = self.base_limits()
        for name, limit, edge, step in (("forward", base["vx"][1], e.forward, "max_step_forward"), ("backward", -base["vx"][0], e.backward, "max_step_backward"),
                                        ("lateral", base["vy"][1], e.lateral, "max_extra_width"), ("turning", base["yaw_rate"][1], e.turning, "max_step_yaw")):  # fmt: skip
            if edge <= limit:
                continue
            per_step = 1.0 if name in ("forward", "backward") else 2.0
            for fraction in np.linspace(0.0, 1.0, 21):
                gait = self._interpolated(float(fraction))
                needed = per_step * (limit + fraction * (edge - limit)) * gait.step_period
                if needed > getattr(gait, step) + 1e-9:
                    raise ValueError(f"gait envelope: {name} {limit + fraction * (edge - limit):.3g} needs a step of {needed:.3g} > {step} {getattr(gait, step):.3g}")


@dataclass
class ClampedCommand:
    command: VelocityCommand
    notes: list[str] = field(default_factory=list)

    @property
    def clamped(self) -> bool:
        return bool(self.notes)


class FootstepPlanner:
    """Footsteps from a velocity command (see the module docstring)."""

    def __init__(self, config: GaitConfig | None = None) -> None:
        self.config = config or GaitConfig()
        # (vx, vy) m/s added to a command's non-zero components when stepping (at most half of each,
        # never flipping its sign): a walker's velocity correction; (0, 0): none.
        self.correction = (0.0, 0.0)
        # (x, y) m/s, in the step's mean heading: every planned landing moved by this × the step period
        # after the plan (the turn compensation does not undo it), so the feet's middle goes this much
        # faster along / across the heading whatever the command's components (zero ones too): a
        # walker's drift correction; (0, 0): none.
        self.offset = (0.0, 0.0)
        self._compensated: dict[tuple[float, float, float], VelocityCommand] = {}  # turn_compensated's

    def limits(self) -> dict[str, tuple[float, float]]:
        """The velocity ranges walked (:meth:`GaitConfig.limits`): ``{"vx": (lo, hi), "vy": …, "yaw_rate": …}``."""
        return self.config.limits()

    def clamp(self, command: VelocityCommand | tuple[float, float, float]) -> ClampedCommand:
        """The command inside the limits, with a note per clamped component (``ValueError`` if not finite)."""
        if not isinstance(command, VelocityCommand):
            command = VelocityCommand(*(float(x) for x in command))
        values = {"vx": command.vx, "vy": command.vy, "yaw_rate": command.yaw_rate}
        notes = []
        for name, (lo, hi) in self.limits().items():
            value = float(values[name])
            clipped = min(max(value, lo), hi)
            if clipped != value:
                notes.append(f"{name} = {value:g} is beyond the gait limits [{lo:.3g}, {hi:.3g}]: clamped to {clipped:.3g}")
            values[name] = clipped
        envelope = self.config.envelope
        fraction = self.config.envelope_fraction(VelocityCommand(**values))
        if envelope is not None and fraction > 0.0:
            # On the envelope, the other components within a shrinking share of their base limits.
            base = self.config.base_limits()
            widened = max(values, key=lambda name: self.config.envelope_fraction(VelocityCommand(**{name: values[name]})))
            share = 1.0 - envelope.combined * fraction
            for name, (lo, hi) in base.items():
                value = values[name]
                clipped = min(max(value, share * lo), share * hi)
                if name != widened and clipped != value:
                    notes.append(f"{name} = {value:g} with {widened} = {values[widened]:.3g} beyond the base gait's limits: clamped to {clipped:.3g} "
                                 f"({share:.0%} of its base limit)")
                    values[name] = clipped
        bound = self.config.backward_turning
        if bound is not None and values["vx"] < 0.0 and values["yaw_rate"] != 0.0:
            # Backward while turning: |vx| / its base limit + |yaw rate| / its (at most 1) within ``bound``.
            base = self.config.base_limits()
            turning = min(abs(values["yaw_rate"]) / base["yaw_rate"][1], 1.0)
            slowest = -base["vx"][0] * max(bound - turning, 0.0)
            if -values["vx"] > slowest:
                notes.append(f"vx = {values['vx']:.3g} with yaw_rate = {values['yaw_rate']:.3g}: backward while turning, clamped to {-slowest:.3g}")
                values["vx"] = -slowest
        return ClampedCommand(VelocityCommand(**values), notes)

    def first_swing_side(self, command: VelocityCommand) -> str:
        """The leading foot for lateral motion or turning; the right foot otherwise."""
        lateral = command.vy if command.vy != 0.0 else command.yaw_rate
        return "left" if lateral > 0.0 else "right"

    def next_step(self, stance: Footstep, command: VelocityCommand, leading_yaw: float | None = None) -> Footstep:
        """The next footstep (the other foot) from ``stance`` for a command inside the limits, at
        this planner's gait (a command beyond its base limits: plan with ``config.for_command``'s).
        ``leading_yaw`` (rad): a leading turning step's yaw relative to ``stance`` instead of
        ``2 · yaw_rate · T`` (within the step limits; a closed-loop heading, see the walker)."""
        if self.correction != (0.0, 0.0):
            command = self.corrected(command)
        if command.yaw_rate != 0.0:
            command = self.turn_compensated(command)
        step = self._step(stance, command, leading_yaw)
        if self.offset == (0.0, 0.0):
            return step
        T = self.config.step_period
        heading = stance.yaw + 0.5 * wrap_angle(step.yaw - stance.yaw)
        x, y = rotate(math.cos(heading), math.sin(heading), self.offset[0] * T, self.offset[1] * T)
        return Footstep(step.side, [float(step.position[0]) + x, float(step.position[1]) + y], step.yaw)

    @property
    def forward_reach(self) -> float:
        """The longest forward step (m): ``max_step_forward``, plus ``CORRECTION_REACH`` while the
        velocity correction lengthens the steps (the adapter shortens them: at 0.652 m/s, nominal
        0.30 m steps walked 0.595 m/s; 0.612 with this reach)."""
        return self.config.max_step_forward + (CORRECTION_REACH if self.correction[0] > 0.0 else 0.0)

    def turn_compensated(self, command: VelocityCommand) -> VelocityCommand:
        """The command whose turning steps walk ``command``: a turning plan's feet's middle, in the
        feet's mean heading, drifts from the linear velocity asked (the base gait's (0.5, 0, 0.5):
        (0.544, -0.069) m/s over a cycle: each step goes along its stance sole's heading and the
        feet turn about a sole); ``TURN_COMPENSATION_ITERATIONS`` fixed-point passes over
        :meth:`cycle_velocity` remove it (within the step limits). Cached per command."""
        key = (command.vx, command.vy, command.yaw_rate)
        cached = self._compensated.get(key)
        if cached is not None:
            return cached
        c = self.config
        T = c.step_period
        lo_x, hi_x = -c.max_step_backward / T, c.max_step_forward / T
        vy_max = c.max_extra_width / (2.0 * T)
        vx, vy = command.vx, command.vy
        for _ in range(TURN_COMPENSATION_ITERATIONS):
            ax, ay = self.cycle_velocity(VelocityCommand(vx, vy, command.yaw_rate))
            vx = min(max(vx + command.vx - ax, lo_x), hi_x)
            vy = min(max(vy + command.vy - ay, -vy_max), vy_max)
            # Never a lateral lead against the turn's (nor against the command's own vy): the feet's
            # pattern would flip (backward turning at (-0.2, 0, 0.5) fell with it).
            lead = command.vy if command.vy != 0.0 else command.yaw_rate
            if vy * lead < 0.0:
                vy = 0.0
        compensated = self._compensated[key] = VelocityCommand(vx, vy, command.yaw_rate)
        return compensated

    def cycle_velocity(self, command: VelocityCommand) -> tuple[float, float]:
        """The velocity ``(vx, vy)`` m/s of the feet's middle in the feet's mean heading over a step
        cycle (two steps) of this plan for ``command`` (uncompensated, no correction), from the
        feet side by side: the cycle after ``TURN_COMPENSATION_WARMUP`` steps."""
        half = 0.5 * self.config.step_width
        feet = {"left": Footstep("left", [0.0, half]), "right": Footstep("right", [0.0, -half])}
        stance = feet[other_side(self.first_swing_side(command))]
        poses = []
        for _ in range(TURN_COMPENSATION_WARMUP + 2):
            stance = self._step(stance, command, None)
            feet[stance.side] = stance
            left, right = feet["left"], feet["right"]
            poses.append((0.5 * (left.position + right.position), left.yaw + 0.5 * wrap_angle(right.yaw - left.yaw)))
        (m0, h0), (m1, h1) = poses[-3], poses[-1]
        heading = h0 + 0.5 * wrap_angle(h1 - h0)
        d = (m1 - m0) / (2.0 * self.config.step_period)
        return float(math.cos(heading) * d[0] + math.sin(heading) * d[1]), float(-math.sin(heading) * d[0] + math.cos(heading) * d[1])

    def _step(self, stance: Footstep, command: VelocityCommand, leading_yaw: float | None) -> Footstep:
        """:meth:`next_step` for a command as it is planned (corrected and compensated already)."""
        c = self.config
        T = c.step_period
        side = other_side(stance.side)
        sign = side_sign(side)
        dx = min(max(command.vx * T, -c.max_step_backward), self.forward_reach)
        lateral = command.vy * sign > 0.0
        extra = min(2.0 * abs(command.vy) * T, c.max_extra_width) if lateral else 0.0
        dy = sign * (c.step_width + extra)
        leading_turn = command.yaw_rate * sign > 0.0
        dyaw = float(np.clip(2.0 * command.yaw_rate * T if leading_yaw is None else leading_yaw, -c.max_step_yaw, c.max_step_yaw)) if leading_turn else 0.0
        if c.turn_about_centre and dyaw != 0.0:
            # The leading foot's nominal spot turned by dyaw about the point between the feet (not
            # about the stance sole): the trailing foot, placed the nominal width across it, then
            # brings the feet's middle back where it was.
            half = 0.5 * c.step_width
            position = stance.to_world([dx - math.sin(dyaw) * sign * (half + extra), sign * half + math.cos(dyaw) * sign * (half + extra)])
        else:
            position = stance.to_world([dx, dy])
        return Footstep(side, position, wrap_angle(stance.yaw + dyaw))

    def corrected(self, command: VelocityCommand) -> VelocityCommand:
        """``command`` with :attr:`correction` added to its non-zero components (each change at
        most half the component: the step pattern's leading foot stays the same)."""
        vx, vy = command.vx, command.vy
        cx, cy = self.correction
        vx += min(max(cx, -0.5 * abs(vx)), 0.5 * abs(vx))
        vy += min(max(cy, -0.5 * abs(vy)), 0.5 * abs(vy))
        return VelocityCommand(vx, vy, command.yaw_rate)

    def plan(self, stance: Footstep, command: VelocityCommand | tuple[float, float, float], n: int) -> tuple[list[Footstep], list[str]]:
        """``n`` footsteps after ``stance`` (alternating, starting with the other foot) and the
        clamp notes of the command."""
        if n < 0:
            raise ValueError("the number of footsteps must be >= 0")
        clamped = self.clamp(command)
        gait = self.config.for_command(clamped.command)
        planner = self if gait is self.config else FootstepPlanner(gait)
        steps: list[Footstep] = []
        current = stance
        for _ in range(n):
            current = planner.next_step(current, clamped.command)
            steps.append(current)
        return steps, clamped.notes

    def constrain(self, stance: Footstep, step: Footstep) -> Footstep:
        """``step`` moved into the kinematic limits relative to ``stance`` (no crossing: at least
        ``min_width`` on its own side; length, extra width and yaw bounded)."""
        c = self.config
        local, yaw = stance.relative(step)
        lo, hi = self.lateral_range(step.side)
        local = np.array([min(max(local[0], -c.max_step_backward), self.forward_reach), min(max(local[1], lo), hi)])
        sign = side_sign(step.side)
        outward = yaw * sign
        outward = min(max(outward, -c.max_inward_yaw), c.max_step_yaw)
        return Footstep(step.side, stance.to_world(local), wrap_angle(stance.yaw + outward * sign))

    def lateral_range(self, side: str) -> tuple[float, float]:
        """Allowed lateral position (stance frame) of a ``side`` foot: ``[lo, hi]``."""
        c = self.config
        near, far = c.min_width, c.step_width + c.max_extra_width
        return (near, far) if side_sign(side) > 0 else (-far, -near)
