"""Plain, validated settings of the insertion task; every field has a key in conf/env/insertion.yaml."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np

from vitac.envs import props
from vitac.sensors.tactile import PEG_SHAPES, PegGeometry
from vitac.utils.checks import refuse

OBSERVATIONS = ("proprio", "peg_state", "contact_forces", "wrist", "tactile_left", "tactile_right", "critic_state")


@dataclass
class Randomization:
    """Per-episode ranges [low, high] of the paper's appendix table; `enabled: false` uses the midpoints.

    `scale` shrinks every range about its midpoint (1 is the paper's randomization); a training
    curriculum raises it towards 1 (see `algo.curriculum`).
    """

    enabled: bool = True
    scale: float = 1.0
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
class InsertionConfig:
    """Settings of the insertion task. See conf/env/insertion.yaml for each key's meaning."""

    peg_shape: str = "round"
    peg_size: int = 16
    control_hz: float = 60.0
    physics_substeps: int = 8
    episode_steps: int = 255
    pos_action_scale: float = 0.01
    rot_action_scale: float = 0.05
    prop_gains: list = field(default_factory=lambda: [600.0, 600.0, 600.0, 50.0, 50.0, 50.0])
    deriv_gains: list = field(default_factory=lambda: [50.0, 50.0, 50.0, 1.41, 1.41, 1.41])
    hand_mass: float = 1.0
    hand_inertia: float = 0.005
    joint_damping: float = 1.5
    finger_kp: float = 400.0
    finger_kd: float = 2.0
    peg_friction: float = 1.0
    socket_friction: float = 0.5
    # Time constant (s) of the socket's contacts (MuJoCo solref): stiff enough that a fully inserted peg
    # tilts no further than the clearance allows, as with TacSL's rigid PhysX contacts.
    socket_contact_timeconst: float = 0.005
    pad_friction: float = 1.0
    density: float = 8000.0
    clearance: float | None = None  # diametral clearance (m); None takes TacSL's for the peg size
    taxel_rows: int = 32
    taxel_cols: int = 32
    taxel_margin: float = 0.0005
    tactile_kn: float = 1000.0
    tactile_kt: float = 100.0
    tactile_mu: float = 2.0
    tactile_residual: bool = True
    camera_size: int = 64
    camera_fovy: float = 75.0
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
    observations: list = field(default_factory=lambda: list(OBSERVATIONS))
    randomization: Randomization = field(default_factory=Randomization)

    @classmethod
    def from_dict(cls, values: dict | None) -> InsertionConfig:
        values = dict(values or {})
        values.pop("_target_", None)
        known = {f.name for f in fields(cls)}
        for key in values:
            if key not in known:
                refuse(f"env.{key}", values[key], f"one of {sorted(known)}")
        rand = dict(values.pop("randomization", None) or {})
        rand_known = {f.name for f in fields(Randomization)}
        for key in rand:
            if key not in rand_known:
                refuse(f"env.randomization.{key}", rand[key], f"one of {sorted(rand_known)}")
        cfg = cls(**values, randomization=Randomization(**rand))
        cfg.validate()
        return cfg

    def to_dict(self) -> dict:
        return asdict(self)

    def validate(self) -> None:
        if self.peg_shape not in PEG_SHAPES:
            refuse("env.peg_shape", self.peg_shape, f"one of {list(PEG_SHAPES)}")
        if self.peg_size not in props.ROUND_PEG_DIAMETER:
            refuse("env.peg_size", self.peg_size, f"one of {sorted(props.ROUND_PEG_DIAMETER)} (mm)")
        for key in ("physics_substeps", "episode_steps", "taxel_rows", "taxel_cols", "camera_size", "num_keypoints"):
            value = getattr(self, key)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
                refuse(f"env.{key}", value, "a positive integer")
        for key in ("control_hz", "pos_action_scale", "rot_action_scale", "hand_mass", "hand_inertia", "finger_kp",
                    "density", "tactile_kn", "success_threshold", "camera_fovy", "keypoint_scale"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
                refuse(f"env.{key}", value, "a number > 0")
        for key in ("peg_friction", "socket_friction", "pad_friction", "tactile_kt", "tactile_mu", "joint_damping",
                    "finger_kd", "taxel_margin", "keypoint_reward_scale", "action_gradient_penalty_scale",
                    "lateral_reward_scale", "success_reward_scale"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                refuse(f"env.{key}", value, "a number >= 0")
        for key in ("prop_gains", "deriv_gains"):
            value = getattr(self, key)
            if len(value) != 6 or any(v < 0 for v in value):
                refuse(f"env.{key}", value, "6 non-negative numbers (3 translational, 3 rotational)")
        min_timeconst = 2.0 / (self.control_hz * self.physics_substeps)
        if not isinstance(self.socket_contact_timeconst, (int, float)) or not self.socket_contact_timeconst >= min_timeconst:
            refuse("env.socket_contact_timeconst", self.socket_contact_timeconst,
                  f"a time constant >= 2 physics timesteps ({min_timeconst:.4g} s), which MuJoCo needs for stability")
        if self.camera_fovy >= 180:
            refuse("env.camera_fovy", self.camera_fovy, "a field of view below 180 degrees")
        if self.clearance is not None and not self.clearance > 0:
            refuse("env.clearance", self.clearance, "a diametral clearance > 0 (m), or null for TacSL's")
        if 2 * self.taxel_margin >= min(0.024, 0.032):
            refuse("env.taxel_margin", self.taxel_margin, "less than half the pad width (0.012 m)")
        unknown = [o for o in self.observations if o not in OBSERVATIONS]
        if unknown:
            refuse("env.observations", list(self.observations), f"a subset of {list(OBSERVATIONS)}")
        r = self.randomization
        for key in ("ee_pos", "ee_rot", "socket_pos"):
            low, high = getattr(r, f"{key}_low"), getattr(r, f"{key}_high")
            if len(low) != 3 or len(high) != 3 or any(lo > hi for lo, hi in zip(low, high, strict=True)):
                refuse(f"env.randomization.{key}_low/high", (low, high), "two lists of 3 with low <= high")
        for key in ("peg_in_hand_depth", "peg_in_hand_tilt", "pad_stiffness", "pad_damping", "joint_damping_noise"):
            value = getattr(r, key)
            if len(value) != 2 or value[0] > value[1]:
                refuse(f"env.randomization.{key}", value, "[low, high] with low <= high")
        depth = r.peg_in_hand_depth
        if depth[0] <= 0.0 or depth[1] >= props.PEG_LENGTH:
            refuse("env.randomization.peg_in_hand_depth", depth,
                  f"a range inside (0, {props.PEG_LENGTH}) m so that the pads hold the peg")
        if r.pad_stiffness[0] <= 0 or r.pad_damping[0] < 0:
            refuse("env.randomization.pad_stiffness/pad_damping", (r.pad_stiffness, r.pad_damping),
                  "stiffness > 0 and damping >= 0")
        if isinstance(r.scale, bool) or not isinstance(r.scale, (int, float)) or not 0.0 <= r.scale <= 1.0:
            refuse("env.randomization.scale", r.scale, "a number in [0, 1] (1 is the paper's randomization)")
        if r.socket_obs_noise < 0:
            refuse("env.randomization.socket_obs_noise", r.socket_obs_noise, "a number >= 0")
        if self.joint_damping + r.joint_damping_noise[0] < 0:
            refuse("env.randomization.joint_damping_noise", r.joint_damping_noise,
                  f"a range that keeps joint damping ({self.joint_damping}) non-negative")
        peg, hole = self.peg_geometry(), self.hole_half_extents()
        if hole[0] <= peg.half_x or (self.peg_shape == "rectangular" and hole[1] <= peg.half_y):
            refuse("env.clearance", self.clearance, "a clearance that leaves the hole wider than the peg")

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


def observation_shapes(config: InsertionConfig) -> dict[str, tuple]:
    """Shape of every observation the task can produce, known without building the simulation."""
    tactile = (3, config.taxel_rows, config.taxel_cols)
    return dict(proprio=(19,), peg_state=(10,), contact_forces=(9,), critic_state=(42,),
                wrist=(3, config.camera_size, config.camera_size), tactile_left=tactile, tactile_right=tactile)
