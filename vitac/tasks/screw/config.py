"""Plain, validated settings of the screw task; every field has a key in conf/task/screw.yaml."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

from vitac.tasks.config import GraspRandomization, GraspTaskConfig, ObservationSpec
from vitac.tasks.screw import props
from vitac.utils.checks import check_flag, refuse


@dataclass
class Randomization(GraspRandomization):
    """Per-episode ranges [low, high] of the start (and `enabled`, `scale`)."""

    bolt_pos_low: list = field(default_factory=lambda: [0.45, -0.05])
    bolt_pos_high: list = field(default_factory=lambda: [0.55, 0.05])
    # Turns of thread between the nut and its goal: sets the nut's height and its yaw on the thread together.
    start_turns: list = field(default_factory=lambda: [3.0, 3.5])
    # start=off_thread: the nut's bottom this high above the bolt's tip (m), its axis this far off the bolt's (x, y in
    # m), its yaw (rad; the thread's phase then is anything), and the bolt's observed position off by up to
    # bolt_obs_noise (m, x and y) for the episode.
    hover: list = field(default_factory=lambda: [0.002, 0.005])
    start_offset_low: list = field(default_factory=lambda: [-0.002, -0.002])
    start_offset_high: list = field(default_factory=lambda: [0.002, 0.002])
    start_yaw: list = field(default_factory=lambda: [-math.pi, math.pi])
    bolt_obs_noise: float = 0.0
    # Nut bottom above the fingertips (m), and its offset along the pads (across the closing axis).
    grasp_depth: list = field(default_factory=lambda: [0.001, 0.004])
    grasp_offset: list = field(default_factory=lambda: [-0.002, 0.002])
    # start=off_thread: the nut tilted in the grasp (rad) about the pads' normal through its centre, unobserved.
    grasp_tilt: list = field(default_factory=lambda: [0.0, 0.0])
    pad_stiffness: list = field(default_factory=lambda: [150.0, 350.0])
    pad_damping: list = field(default_factory=lambda: [0.0, 1.0])
    joint_damping_noise: list = field(default_factory=lambda: [-1.5, 1.5])


@dataclass
class ScrewConfig(GraspTaskConfig):
    """Settings of the screw task (Factory's NutBoltScrew). See conf/task/screw.yaml for each key's meaning."""

    RANDOMIZATION: ClassVar[type] = Randomization
    TASK: ClassVar[str] = "vitac.tasks.screw.task.ScrewTask"
    ORACLE: ClassVar[str] = "vitac.tasks.screw.oracle.OracleController"

    # engaged: the nut starts on the thread, `start_turns` above its goal (the paper's figure); off_thread: above
    # the bolt's tip, not engaged (Factory's NutThread), so a policy must align it and find the thread.
    start: str = "engaged"
    episode_steps: int = 300
    # 1/240 s physics steps, twice Factory's rate (1/60 s, 2 substeps); stable with the thread's 0.01 s contacts.
    physics_substeps: int = 4
    # A stiffer yaw drive than insertion's (Factory's z-rotation gain is 100x its others): the hand then turns
    # the nut at about 0.07 rad a step under the full action instead of 0.03.
    prop_gains: list = field(default_factory=lambda: [600.0, 600.0, 600.0, 150.0, 50.0, 50.0])
    rot_action_scale: float = 0.1  # Factory's rot_action_scale (rad a step)
    # Factory's motion_ctrl_axes: the hand is driven along z and about z only; the other four action
    # components are ignored and the hand is compliant along them.
    action_axes: list = field(default_factory=lambda: [0, 0, 1, 0, 0, 1])
    # Factory's unidirectional_rot: the z-rotation action turns the nut only the tightening way (clockwise seen
    # from above), a in [-1, 1] mapped to -(a + 1) / 2 of the full step.
    unidirectional_rotation: bool = False
    nut_friction: float = 0.3  # Factory's
    bolt_friction: float = 0.3
    bolt_contact_timeconst: float = 0.01
    segments_per_turn: int = 24
    # Turns of the nut's thread in contact with the bolt's: 3 of the 6.5 an M16 nut has (the first turns carry
    # most of a real thread's load); contacts, the physics' cost, scale with it.
    nut_thread_turns: float = 3.0
    success_pitches: float = 2.0  # success: the nut within this many thread pitches of resting on the bolt's head
    far_distance: float = 0.1  # Factory's far_error_thresh (m)
    keypoint_length: float = 0.112071  # Factory's keypoint axis: franka hand + finger length (m)
    num_keypoints: int = 4
    keypoint_reward_scale: float = 1.0
    action_gradient_penalty_scale: float = 0.0
    # A failure that ends the episode also earns its step's reward once for every step left to the time limit, as
    # if the nut had stayed where it failed: with a reward below 0 at every step, ending early must not pay.
    charge_failures_to_time_limit: bool = False
    randomization: Randomization = field(default_factory=Randomization)

    def task_observation_specs(self) -> dict[str, ObservationSpec]:
        # The insertion task's names and sizes, so that every observation group composes for both tasks:
        # `peg_state` is the held part's (here the nut's) state. Each vector ends with its offset to the goal.
        return dict(proprio=ObservationSpec((19,)), peg_state=ObservationSpec((10,)),
                    critic_state=ObservationSpec((42,), needs_contact_forces=True, critic_only=True))

    @property
    def success_distance(self) -> float:
        return self.success_pitches * props.PITCH

    def validate(self) -> None:
        super().validate()
        check_flag("task.unidirectional_rotation", self.unidirectional_rotation)
        check_flag("task.charge_failures_to_time_limit", self.charge_failures_to_time_limit)
        axes = self.action_axes
        if len(axes) != 6 or any(a not in (0, 1) for a in axes) or not any(axes):
            refuse("task.action_axes", axes, "6 flags of 0 or 1 (x, y, z, roll, pitch, yaw), at least one 1")
        for key in ("segments_per_turn", "num_keypoints"):
            value = getattr(self, key)
            if not isinstance(value, int) or isinstance(value, bool) or value < (8 if key == "segments_per_turn" else 1):
                refuse(f"task.{key}", value, "an integer >= 8" if key == "segments_per_turn" else "a positive integer")
        max_turns = props.NUT_HEIGHT / props.PITCH - 2 * props.THREAD_TUBE / props.PITCH
        if isinstance(self.nut_thread_turns, bool) or not 1 <= self.nut_thread_turns <= max_turns:
            refuse("task.nut_thread_turns", self.nut_thread_turns, f"a number of turns in [1, {max_turns:.2f}]")
        for key in ("success_pitches", "far_distance", "keypoint_length", "bolt_contact_timeconst"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
                refuse(f"task.{key}", value, "a number > 0")
        for key in ("nut_friction", "bolt_friction", "keypoint_reward_scale", "action_gradient_penalty_scale"):
            value = getattr(self, key)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or value < 0:
                refuse(f"task.{key}", value, "a number >= 0")
        min_timeconst = 2.0 / (self.control_hz * self.physics_substeps)
        if not self.bolt_contact_timeconst >= min_timeconst:
            refuse("task.bolt_contact_timeconst", self.bolt_contact_timeconst,
                   f"a time constant >= 2 physics timesteps ({min_timeconst:.4g} s), which MuJoCo needs for stability")
        if self.start not in STARTS:
            refuse("task.start", self.start, f"one of {list(STARTS)}")
        r = self.randomization
        for key in ("bolt_pos_low", "bolt_pos_high", "start_offset_low", "start_offset_high"):
            if len(getattr(r, key)) != 2:
                refuse(f"task.randomization.{key}", getattr(r, key), "2 numbers (x, y in m)")
        if not r.bolt_obs_noise >= 0:
            refuse("task.randomization.bolt_obs_noise", r.bolt_obs_noise, "a number >= 0")
        if r.hover[0] < 0:
            refuse("task.randomization.hover", r.hover, "a range of heights >= 0 above the bolt's tip")
        for key in ("start_turns", "hover", "start_yaw", "grasp_depth", "grasp_offset", "grasp_tilt", "pad_stiffness",
                    "pad_damping", "joint_damping_noise"):
            value = getattr(r, key)
            if len(value) != 2 or value[0] > value[1]:
                refuse(f"task.randomization.{key}", value, "[low, high] with low <= high")
        max_turns = props.SHANK_LENGTH / props.PITCH - props.NUT_HEIGHT / props.PITCH
        if r.start_turns[0] <= self.success_pitches or r.start_turns[1] > max_turns:
            refuse("task.randomization.start_turns", r.start_turns,
                   f"a range above task.success_pitches ({self.success_pitches}) and at most {max_turns:g} turns "
                   "(the nut's top at the bolt's end)")
        if r.grasp_depth[0] < 0 or r.grasp_depth[1] > 0.032 - props.NUT_HEIGHT:
            refuse("task.randomization.grasp_depth", r.grasp_depth,
                   f"a range in [0, {0.032 - props.NUT_HEIGHT:g}] m so that the fingertips stay off the bolt's head "
                   "and the pads cover the nut")
        if abs(r.grasp_offset[0]) > 0.005 or abs(r.grasp_offset[1]) > 0.005:
            refuse("task.randomization.grasp_offset", r.grasp_offset, "a range within [-0.005, 0.005] m")
        if max(abs(r.grasp_tilt[0]), abs(r.grasp_tilt[1])) > math.radians(15):
            refuse("task.randomization.grasp_tilt", r.grasp_tilt, "a range within [-0.26, 0.26] rad (15 deg)")
        if r.pad_stiffness[0] <= 0 or r.pad_damping[0] < 0:
            refuse("task.randomization.pad_stiffness/pad_damping", (r.pad_stiffness, r.pad_damping),
                   "stiffness > 0 and damping >= 0")
        if self.joint_damping + r.joint_damping_noise[0] < 0:
            refuse("task.randomization.joint_damping_noise", r.joint_damping_noise,
                   f"a range that keeps joint damping ({self.joint_damping}) non-negative")


STARTS = ("engaged", "off_thread")


def thread_yaw(height: float) -> float:
    """The nut's yaw (rad) at which its thread engages the bolt's with its bottom `height` above the bolt's origin."""
    return 2 * math.pi * height / props.PITCH
