"""Settings every grasped-part task shares (robot, sensors, control) and the declaration of an observation."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import ClassVar

import numpy as np

from vitac.utils.checks import check_flag, refuse, refuse_non_finite


@dataclass(frozen=True)
class ObservationSpec:
    """One observation a task can produce, known without building the simulation.

    Args:
        shape: array shape of one step's value.
        kind: "image" (uint8 or float maps read by an image encoder) or "vector".
        role: for images, the fusion role ("vision", "left", "right"); None for vectors.
        needs_contact_forces: computing it reads the last substep's contact forces (kept only when observed).
        critic_only: the asymmetric critic's input, never the actor's.
    """

    shape: tuple
    kind: str = "vector"
    role: str | None = None
    needs_contact_forces: bool = False
    critic_only: bool = False


@dataclass
class GraspRandomization:
    """Per-episode ranges [low, high] a task samples; `enabled: false` uses the midpoints.

    `scale` shrinks every range about its midpoint (1 is the paper's randomization); a training
    curriculum raises it towards 1 (`curriculum=randomization`).
    """

    enabled: bool = True
    scale: float = 1.0


@dataclass
class GraspTaskConfig:
    """The robot, its sensors and its control, shared by every task. See conf/task/<name>.yaml for each key."""

    RANDOMIZATION: ClassVar[type] = GraspRandomization
    TASK: ClassVar[str] = ""  # dotted path of the composer Task these settings build
    ORACLE: ClassVar[str] = ""  # dotted path of its scripted controller: oracle(task)(physics) -> action
    TASK_KEY: ClassVar[str] = "task"  # the config key refusals name

    name: str = ""  # the conf/task file that composed it: reports group runs by task with it
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
    pad_friction: float = 1.0
    # MuJoCo's noslip solver passes per physics step (0: off): soft contacts let a held part creep along the pads
    # under a steady push, a slip PhysX's static friction does not have (docs/environment.md).
    noslip_iterations: int = 0
    taxel_rows: int = 32
    taxel_cols: int = 32
    taxel_margin: float = 0.0005
    tactile_kn: float = 1000.0
    tactile_kt: float = 100.0
    tactile_mu: float = 2.0
    tactile_residual: bool = True
    measure_force_balance: bool = False  # vitac.evaluate turns it on: the pads' asymmetry per episode (sim/balance.py)
    # A reward penalty of this times the pads' field asymmetry at each step (sim/balance.py; 0: off): the symmetry
    # prior's aim put into the objective instead of into the embeddings.
    balance_penalty_scale: float = 0.0
    camera_size: int = 64
    camera_fovy: float = 75.0
    observations: list = field(default_factory=list)  # empty: every declared observation
    randomization: GraspRandomization = field(default_factory=GraspRandomization)

    def __post_init__(self):
        if not self.observations:
            self.observations = list(self.observation_specs())

    @classmethod
    def from_dict(cls, values: dict | None):
        """A validated config from plain keys, refusing an unknown key by name."""
        values = dict(values or {})
        values.pop("_target_", None)
        key = cls.TASK_KEY
        known = {f.name for f in fields(cls)}
        for name in values:
            if name not in known:
                refuse(f"{key}.{name}", values[name], f"one of {sorted(known)}")
        rand = dict(values.pop("randomization", None) or {})
        rand_known = {f.name for f in fields(cls.RANDOMIZATION)}
        for name in rand:
            if name not in rand_known:
                refuse(f"{key}.randomization.{name}", rand[name], f"one of {sorted(rand_known)}")
        cfg = cls(**values, randomization=cls.RANDOMIZATION(**rand))
        cfg.validate()
        return cfg

    def to_dict(self) -> dict:
        """Plain keys that `vitac.tasks.make_task_config` turns back into this config."""
        return dict(asdict(self), _target_=f"{type(self).__module__}.{type(self).__name__}")

    def build_task(self, offscreen_size: int | None = None):
        """The composer Task of these settings."""
        from vitac.tasks import import_object

        return import_object(self.TASK)(self, offscreen_size=offscreen_size)

    def observation_specs(self) -> dict[str, ObservationSpec]:
        """Every observation of the task, in a fixed order: the shared sensors' and the task's own."""
        tactile = (3, self.taxel_rows, self.taxel_cols)
        return dict(self.task_observation_specs(), contact_forces=ObservationSpec((9,), needs_contact_forces=True),
                    wrist=ObservationSpec((3, self.camera_size, self.camera_size), "image", "vision"),
                    tactile_left=ObservationSpec(tactile, "image", "left"),
                    tactile_right=ObservationSpec(tactile, "image", "right"))

    def observation_shapes(self) -> dict[str, tuple]:
        return {name: spec.shape for name, spec in self.observation_specs().items()}

    def task_observation_specs(self) -> dict[str, ObservationSpec]:
        """The task's own vector observations (proprioception, privileged state, critic state)."""
        raise NotImplementedError

    def validate(self) -> None:
        key = self.TASK_KEY
        refuse_non_finite(asdict(self), key)
        for name in ("physics_substeps", "episode_steps", "taxel_rows", "taxel_cols", "camera_size"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
                refuse(f"{key}.{name}", value, "a positive integer")
        if not isinstance(self.noslip_iterations, (int, np.integer)) or isinstance(self.noslip_iterations, bool) \
                or self.noslip_iterations < 0:
            refuse(f"{key}.noslip_iterations", self.noslip_iterations, "an integer >= 0 (0: no noslip solver)")
        for name in ("control_hz", "pos_action_scale", "rot_action_scale", "hand_mass", "hand_inertia", "finger_kp",
                     "tactile_kn", "camera_fovy"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
                refuse(f"{key}.{name}", value, "a number > 0")
        for name in ("pad_friction", "tactile_kt", "tactile_mu", "joint_damping", "finger_kd", "taxel_margin",
                     "balance_penalty_scale"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                refuse(f"{key}.{name}", value, "a number >= 0")
        for name in ("prop_gains", "deriv_gains"):
            value = getattr(self, name)
            if len(value) != 6 or any(v < 0 for v in value):
                refuse(f"{key}.{name}", value, "6 non-negative numbers (3 translational, 3 rotational)")
        check_flag(f"{key}.tactile_residual", self.tactile_residual)
        check_flag(f"{key}.measure_force_balance", self.measure_force_balance)
        check_flag(f"{key}.randomization.enabled", self.randomization.enabled)
        if self.camera_fovy >= 180:
            refuse(f"{key}.camera_fovy", self.camera_fovy, "a field of view below 180 degrees")
        if 2 * self.taxel_margin >= min(0.024, 0.032):
            refuse(f"{key}.taxel_margin", self.taxel_margin, "less than half the pad width (0.012 m)")
        declared = list(self.observation_specs())
        if any(o not in declared for o in self.observations):
            refuse(f"{key}.observations", list(self.observations), f"a subset of {declared}")
        r = self.randomization
        if isinstance(r.scale, bool) or not isinstance(r.scale, (int, float)) or not 0.0 <= r.scale <= 1.0:
            refuse(f"{key}.randomization.scale", r.scale, "a number in [0, 1] (1 is the paper's randomization)")
