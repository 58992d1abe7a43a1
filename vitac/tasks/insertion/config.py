"""Plain, validated settings of the insertion task; every field has a key in conf/task/insertion.yaml."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import ClassVar

from vitac.tasks.config import GraspRandomization, GraspTaskConfig, ObservationSpec
from vitac.tasks.insertion import props
from vitac.tasks.insertion.props import PEG_SHAPES, PegGeometry
from vitac.utils.checks import check_flag, refuse


@dataclass
class Randomization(GraspRandomization):
    """Per-episode ranges [low, high] of the paper's appendix table (and `enabled`, `scale`)."""

    ee_pos_low: list = field(default_factory=lambda: [0.4, -0.1, 0.1])
    ee_pos_high: list = field(default_factory=lambda: [0.6, 0.1, 0.2])
    # Hand orientation as offsets from pointing straight down: roll (about x), pitch (y), yaw (z).
    ee_rot_low: list = field(default_factory=lambda: [-0.1, -0.1, -1.0])
    ee_rot_high: list = field(default_factory=lambda: [0.1, 0.1, 1.0])
    socket_pos_low: list = field(default_factory=lambda: [0.4, -0.1, 0.0])
    socket_pos_high: list = field(default_factory=lambda: [0.6, 0.1, 0.02])
    # Fingertip-midpoint-to-peg-bottom distance: TacSL's sampled range (see docs/environment.md).
    peg_in_hand_depth: list = field(default_factory=lambda: [0.0308, 0.040])
    peg_in_hand_tilt: list = field(default_factory=lambda: [-0.628, 0.628])
    socket_obs_noise: float = 0.005
    pad_stiffness: list = field(default_factory=lambda: [150.0, 350.0])
    pad_damping: list = field(default_factory=lambda: [0.0, 1.0])
    joint_damping_noise: list = field(default_factory=lambda: [-1.5, 1.5])

    def only(self, names) -> Randomization:
        """A copy that randomizes only the named factors (RANDOMIZED_FACTORS): every other range collapses to
        its midpoint and, unless named, the socket observation noise to 0. Which factor does a policy fail on?"""
        unknown = [n for n in names if n not in RANDOMIZED_FACTORS]
        if unknown or not names:
            refuse("randomize_only", list(names), f"a non-empty list of {list(RANDOMIZED_FACTORS)}")
        values = asdict(self)
        for name, keys in RANDOMIZED_FACTORS.items():
            if name in names:
                continue
            if name == "socket_obs_noise":
                values[name] = 0.0
            elif len(keys) == 2:  # per-axis [low...], [high...] lists
                mid = [0.5 * (lo + hi) for lo, hi in zip(values[keys[0]], values[keys[1]], strict=True)]
                values[keys[0]], values[keys[1]] = list(mid), list(mid)
            else:
                lo, hi = values[name]
                values[name] = [0.5 * (lo + hi)] * 2
        return Randomization(**values)


# Each randomized factor of the paper's table and the Randomization fields that hold its range.
RANDOMIZED_FACTORS = {
    "ee_pos": ("ee_pos_low", "ee_pos_high"), "ee_rot": ("ee_rot_low", "ee_rot_high"),
    "socket_pos": ("socket_pos_low", "socket_pos_high"), "peg_in_hand_depth": ("peg_in_hand_depth",),
    "peg_in_hand_tilt": ("peg_in_hand_tilt",), "socket_obs_noise": ("socket_obs_noise",),
    "pad_stiffness": ("pad_stiffness",), "pad_damping": ("pad_damping",), "joint_damping_noise": ("joint_damping_noise",),
}


@dataclass
class InsertionConfig(GraspTaskConfig):
    """Settings of the insertion task. See conf/task/insertion.yaml for each key's meaning."""

    RANDOMIZATION: ClassVar[type] = Randomization
    TASK: ClassVar[str] = "vitac.tasks.insertion.task.InsertionTask"
    ORACLE: ClassVar[str] = "vitac.tasks.insertion.oracle.OracleController"

    peg_shape: str = "round"
    peg_size: int = 16
    peg_friction: float = 1.0
    socket_friction: float = 0.5
    # Time constant (s) of the socket's contacts (MuJoCo solref): stiff enough that a fully inserted peg
    # tilts no further than the clearance allows, as with TacSL's rigid PhysX contacts.
    socket_contact_timeconst: float = 0.005
    density: float = 8000.0
    clearance: float | None = None  # diametral clearance (m); None takes TacSL's for the peg size
    success_threshold: float = 0.0044958
    keypoint_scale: float = 0.5
    num_keypoints: int = 4
    keypoint_reward_scale: float = 0.1
    action_gradient_penalty_scale: float = 0.001
    use_shaped_keypoint_reward: bool = True
    # vitac's optional shaping (0: TacSL's reward): minus this times the peg's horizontal distance (m) from the
    # hole axis, every step. TacSL's keypoint distance barely changes with it while the peg is above the hole.
    lateral_reward_scale: float = 0.0
    # vitac's optional bonus (0: TacSL's reward): this much every step at which the success check holds (keypoint
    # distance under success_threshold). TacSL's reward pays only ~0.006 a step more for a peg fully in than 10 mm in.
    success_reward_scale: float = 0.0
    randomization: Randomization = field(default_factory=Randomization)

    def task_observation_specs(self) -> dict[str, ObservationSpec]:
        # Each vector ends with its offset to the observed socket (docs/environment.md).
        return dict(proprio=ObservationSpec((19,)), peg_state=ObservationSpec((10,)),
                    critic_state=ObservationSpec((42,), needs_contact_forces=True, critic_only=True))

    def validate(self) -> None:
        super().validate()
        check_flag("task.use_shaped_keypoint_reward", self.use_shaped_keypoint_reward)
        if self.peg_shape not in PEG_SHAPES:
            refuse("task.peg_shape", self.peg_shape, f"one of {list(PEG_SHAPES)}")
        if self.peg_size not in props.ROUND_PEG_DIAMETER:
            refuse("task.peg_size", self.peg_size, f"one of {sorted(props.ROUND_PEG_DIAMETER)} (mm)")
        if not isinstance(self.num_keypoints, int) or isinstance(self.num_keypoints, bool) or self.num_keypoints < 1:
            refuse("task.num_keypoints", self.num_keypoints, "a positive integer")
        for key in ("density", "success_threshold", "keypoint_scale"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
                refuse(f"task.{key}", value, "a number > 0")
        for key in ("peg_friction", "socket_friction", "keypoint_reward_scale", "action_gradient_penalty_scale",
                    "lateral_reward_scale", "success_reward_scale"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                refuse(f"task.{key}", value, "a number >= 0")
        min_timeconst = 2.0 / (self.control_hz * self.physics_substeps)
        if not isinstance(self.socket_contact_timeconst, (int, float)) or not self.socket_contact_timeconst >= min_timeconst:
            refuse("task.socket_contact_timeconst", self.socket_contact_timeconst,
                   f"a time constant >= 2 physics timesteps ({min_timeconst:.4g} s), which MuJoCo needs for stability")
        if self.clearance is not None and not self.clearance > 0:
            refuse("task.clearance", self.clearance, "a diametral clearance > 0 (m), or null for TacSL's")
        r = self.randomization
        for key in ("ee_pos", "ee_rot", "socket_pos"):
            low, high = getattr(r, f"{key}_low"), getattr(r, f"{key}_high")
            if len(low) != 3 or len(high) != 3 or any(lo > hi for lo, hi in zip(low, high, strict=True)):
                refuse(f"task.randomization.{key}_low/high", (low, high), "two lists of 3 with low <= high")
        for key in ("peg_in_hand_depth", "peg_in_hand_tilt", "pad_stiffness", "pad_damping", "joint_damping_noise"):
            value = getattr(r, key)
            if len(value) != 2 or value[0] > value[1]:
                refuse(f"task.randomization.{key}", value, "[low, high] with low <= high")
        depth = r.peg_in_hand_depth
        if depth[0] <= 0.0 or depth[1] >= props.PEG_LENGTH:
            refuse("task.randomization.peg_in_hand_depth", depth,
                   f"a range inside (0, {props.PEG_LENGTH}) m so that the pads hold the peg")
        if r.pad_stiffness[0] <= 0 or r.pad_damping[0] < 0:
            refuse("task.randomization.pad_stiffness/pad_damping", (r.pad_stiffness, r.pad_damping),
                   "stiffness > 0 and damping >= 0")
        if r.socket_obs_noise < 0:
            refuse("task.randomization.socket_obs_noise", r.socket_obs_noise, "a number >= 0")
        if self.joint_damping + r.joint_damping_noise[0] < 0:
            refuse("task.randomization.joint_damping_noise", r.joint_damping_noise,
                   f"a range that keeps joint damping ({self.joint_damping}) non-negative")
        peg, hole = self.peg_geometry(), self.hole_half_extents()
        if hole[0] <= peg.half_x or (self.peg_shape == "rectangular" and hole[1] <= peg.half_y):
            refuse("task.clearance", self.clearance, "a clearance that leaves the hole wider than the peg")

    def peg_geometry(self) -> PegGeometry:
        if self.peg_shape == "round":
            radius = 0.5 * props.ROUND_PEG_DIAMETER[self.peg_size]
            return PegGeometry("round", radius, radius, props.PEG_LENGTH)
        width, depth = props.RECT_PEG_SIZE[self.peg_size]
        return PegGeometry("rectangular", 0.5 * width, 0.5 * depth, props.PEG_LENGTH)

    def hole_half_extents(self) -> tuple[float, float]:
        """Half extents of the hole (radius twice for a round hole)."""
        peg = self.peg_geometry()
        if self.peg_shape == "round":
            clearance = self.clearance if self.clearance is not None else (
                props.ROUND_HOLE_DIAMETER[self.peg_size] - props.ROUND_PEG_DIAMETER[self.peg_size])
            return peg.half_x + 0.5 * clearance, peg.half_x + 0.5 * clearance
        width_clearance = self.clearance if self.clearance is not None else (
            props.RECT_HOLE_WIDTH[self.peg_size] - props.RECT_PEG_SIZE[self.peg_size][0])
        # TacSL does not give the rectangular hole's second dimension: use the same clearance.
        return peg.half_x + 0.5 * width_clearance, peg.half_y + 0.5 * width_clearance
