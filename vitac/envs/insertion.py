"""Peg-in-socket insertion as a dm_control composer Task (TacSL's task on MuJoCo)."""

from __future__ import annotations

import logging
import math

import dm_env
import mujoco
import numba
import numpy as np
from dm_control import composer
from dm_control.composer.observation import observable
from dm_control.rl import control
from dm_env import specs

from vitac.envs import props
from vitac.envs.config import InsertionConfig
from vitac.envs.gripper import PAD_LENGTH, PAD_WIDTH, ParallelGripper
from vitac.sensors.tactile import TactileFieldSensor

_DOWN = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # hand frame pointing down: Rx(pi)
PAD_TIMECONST = 0.01  # pad contact time constant (s) at the nominal stiffness 250
SETTLE_SECONDS = 0.25  # TacSL closes the gripper for 30 sim steps of 1/120 s with gravity off


class Arena(composer.Arena):
    """Table with its top at z = 0, lit for a 64x64 wrist camera."""

    def _build(self, offscreen_size: int):
        super()._build(name="arena")
        root = self._mjcf_root
        root.option.set_attributes(cone="elliptic", impratio=10, integrator="implicitfast", noslip_iterations=0)
        root.option.flag.set_attributes(multiccd="enable")
        # An offscreen buffer of the camera's own size, no multisampling and no shadows: 64x64 frames cost a
        # fraction of a millisecond on a software renderer instead of tens.
        root.visual.__getattr__("global").set_attributes(offwidth=offscreen_size, offheight=offscreen_size)
        root.visual.quality.set_attributes(offsamples=0, shadowsize=0, numslices=12, numstacks=4, numquads=1)
        root.visual.map.set_attributes(znear=0.005)
        self._mjcf_root.worldbody.add("light", pos=(0.5, 0, 1.5), dir=(0, 0, -1), castshadow=False)
        self._mjcf_root.worldbody.add("geom", name="table", type="box", size=(0.63, 0.45, 0.02),
                                      pos=(0.5, 0, -0.02), rgba=(0.55, 0.45, 0.35, 1),
                                      contype=1, conaffinity=12)
        self._mjcf_root.worldbody.add("camera", name="outside", pos=(0.5, -0.3, 0.25), xyaxes=(1, 0, 0, 0, 0.55, 0.83),
                                      fovy=45)


# Compiled (numba): these run at every control step, where numpy's per-call overhead on 3-vectors would dominate.
@numba.njit(cache=True)
def euler_zyx_from_matrix(m: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) with m = Rz(yaw) Ry(pitch) Rx(roll)."""
    return (math.atan2(m[1, 0], m[0, 0]), -math.asin(min(max(m[2, 0], -1.0), 1.0)), math.atan2(m[2, 1], m[2, 2]))


@numba.njit(cache=True)
def matrix_from_euler_zyx(yaw: float, pitch: float, roll: float) -> np.ndarray:
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@numba.njit(cache=True)
def axis_angle_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (Rodrigues)."""
    angle = math.sqrt(rotvec[0] ** 2 + rotvec[1] ** 2 + rotvec[2] ** 2)
    if angle <= 1e-6:  # TacSL's clamp_rot_thresh: below it the delta is the identity
        return np.eye(3)
    x, y, z = rotvec[0] / angle, rotvec[1] / angle, rotvec[2] / angle
    s, c = math.sin(angle), math.cos(angle)
    t = 1.0 - c
    return np.array([[c + t * x * x, t * x * y - s * z, t * x * z + s * y],
                     [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
                     [t * x * z - s * y, t * y * z + s * x, c + t * z * z]])


@numba.njit(cache=True)
def hand_target(hand_qpos: np.ndarray, action: np.ndarray, pos_scale: float, rot_scale: float) -> np.ndarray:
    """The six hand joints' targets for an action in [-1, 1]^6: the current pose plus a position delta and an
    axis-angle delta in the world frame applied to the current orientation (TacSL)."""
    target = np.empty(6)
    target[:3] = hand_qpos[:3] + action[:3] * pos_scale
    # The hinges' angles give the orientation relative to _DOWN = diag(1, -1, -1), in which the world-frame
    # delta w reads _DOWN.T w (_DOWN.T R(w) _DOWN = R(_DOWN.T w)).
    rotvec = np.array([action[3], -action[4], -action[5]]) * rot_scale
    current = matrix_from_euler_zyx(hand_qpos[3], hand_qpos[4], hand_qpos[5])
    yaw, pitch, roll = euler_zyx_from_matrix(axis_angle_matrix(rotvec) @ current)
    target[3] = hand_qpos[3] + (yaw - hand_qpos[3] + math.pi) % (2 * math.pi) - math.pi  # no wrap-around jumps
    target[4], target[5] = pitch, roll
    return target


@numba.njit(cache=True)
def mean_keypoint_distance(peg_pos: np.ndarray, peg_xmat: np.ndarray, goal_pos: np.ndarray, offsets: np.ndarray) -> float:
    """Mean distance between keypoints at `offsets` along the peg's z axis (xmat row-major) and the goal's (world z)."""
    total = 0.0
    for offset in offsets:
        dx = peg_pos[0] - goal_pos[0] + offset * peg_xmat[2]
        dy = peg_pos[1] - goal_pos[1] + offset * peg_xmat[5]
        dz = peg_pos[2] - goal_pos[2] + offset * (peg_xmat[8] - 1.0)
        total += math.sqrt(dx * dx + dy * dy + dz * dz)
    return total / offsets.shape[0]


def rotation_vector(m: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix."""
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, m.ravel())
    vec = np.empty(3)
    mujoco.mju_quat2Vel(vec, quat, 1.0)
    return vec


def keypoint_offsets(num: int, scale: float) -> np.ndarray:
    return (np.linspace(0.0, 1.0, num) - 0.5) * scale


@numba.njit(cache=True)
def _peg_contact_forces(pairs, efc_address, dim, frames, efc_force, peg_geom_mask, contact_slot):
    """World-frame force on the peg from each slot's geoms (slot 0 socket, 1 left pad, 2 right pad), summed (3, 3).

    With elliptic cones (the arena's) a contact's force in its own frame is its first `dim` rows of efc_force
    (what mj_contactForce copies): normal, then the two tangential components. One compiled loop instead of
    ~3 us of Python per contact.
    """
    out = np.zeros((3, 3))
    for i in range(pairs.shape[0]):
        peg_first, peg_second = peg_geom_mask[pairs[i, 0]], peg_geom_mask[pairs[i, 1]]
        if peg_first == peg_second or efc_address[i] < 0:
            continue
        slot = contact_slot[pairs[i, 0]] if peg_second else contact_slot[pairs[i, 1]]
        if slot < 0:
            continue
        sign = 1.0 if peg_second else -1.0  # the frame's force is geom1's on geom2
        for j in range(min(dim[i], 3)):
            f = sign * efc_force[efc_address[i] + j]
            for k in range(3):
                out[slot, k] += frames[i, 3 * j + k] * f
    return out


class InsertionTask(composer.Task):
    """Insert a grasped peg into a socket; TacSL's reward, success and randomization.

    Args:
        config: validated task settings.
        offscreen_size: offscreen render buffer (pixels); the camera size unless a tool renders larger views.
    """

    def __init__(self, config: InsertionConfig, offscreen_size: int | None = None):
        self.config = config
        self._arena = Arena(offscreen_size=offscreen_size or config.camera_size)
        self.gripper = ParallelGripper(
            hand_mass=config.hand_mass, hand_inertia=config.hand_inertia, prop_gains=config.prop_gains,
            deriv_gains=config.deriv_gains, joint_damping=config.joint_damping, finger_kp=config.finger_kp,
            finger_kd=config.finger_kd, pad_friction=config.pad_friction, camera_fovy=config.camera_fovy)
        self._arena.attach(self.gripper)
        self.peg_geometry = config.peg_geometry()
        self.peg = props.Peg(self.peg_geometry, density=config.density, friction=config.peg_friction)
        self._peg_frame = self._arena.add_free_entity(self.peg)  # the body carrying the peg's free joint
        hole_x, hole_y = config.hole_half_extents()
        self.socket = props.Socket(config.peg_shape, hole_x, hole_y, friction=config.socket_friction,
                                    contact_timeconst=config.socket_contact_timeconst)
        self._socket_frame = self._arena.attach(self.socket)
        # A mocap body: MuJoCo expects moved static bodies to be mocap (moving body_pos of a static body
        # at run time silently breaks collision detection elsewhere in the scene).
        self._socket_frame.mocap = "true"
        self.set_timesteps(control_timestep=1.0 / config.control_hz,
                           physics_timestep=1.0 / (config.control_hz * config.physics_substeps))
        self.tactile = TactileFieldSensor(config.taxel_rows, config.taxel_cols, PAD_WIDTH, PAD_LENGTH,
                                          config.taxel_margin, config.tactile_kn, config.tactile_kt, config.tactile_mu)
        self._keypoints = keypoint_offsets(config.num_keypoints, config.keypoint_scale)
        self._renderer = None
        self.randomization_scale = config.randomization.scale
        self._cache: dict = {}  # per-physics-state values: tactile fields, contact forces, keypoint distance
        self._observes_contact_forces = bool({"contact_forces", "critic_state"} & set(config.observations))
        self._ids = None
        self._step = 0
        self._prev_action = np.zeros(6)
        self._action_delta = 0.0
        self._socket_noise = np.zeros(3)
        self._f_ref = np.zeros((2, 3, config.taxel_rows, config.taxel_cols))
        self.first_success_step = -1
        self._build_observables()

    # ----------------------------------------------------------------------------------- composer API
    @property
    def root_entity(self):
        return self._arena

    @property
    def task_observables(self):
        return self._observables

    def action_spec(self, physics):
        return specs.BoundedArray((6,), np.float64, -np.ones(6), np.ones(6), name="delta_pose")

    def after_compile(self, physics, random_state):
        bind = physics.bind
        m = physics.model
        self._ids = dict(
            hand_qpos=np.array([m.jnt_qposadr[bind(j).element_id] for j in self.gripper.joints]),
            hand_dof=np.array([m.jnt_dofadr[bind(j).element_id] for j in self.gripper.joints]),
            hand_act=np.array([bind(a).element_id for a in self.gripper.actuators]),
            finger_qpos=np.array([m.jnt_qposadr[bind(j).element_id] for j in self.gripper.finger_joints]),
            finger_act=np.array([bind(a).element_id for a in self.gripper.finger_actuators]),
            tcp=bind(self.gripper.tcp_site).element_id,
            hand_body=bind(self.gripper.hand).element_id,
            pad_sites=[bind(s).element_id for s in self.gripper.pad_sites],
            pad_geoms=[bind(g).element_id for g in self.gripper.pads],
            peg_body=bind(self.peg.body).element_id,
            peg_geoms={bind(self.peg.geom).element_id, bind(self.peg.grasp_geom).element_id},
            peg_qpos=m.jnt_qposadr[m.body_jntadr[bind(self._peg_frame).element_id]],
            # bind() does not accept mocap bodies: look the frame up by name.
            socket_mocap=m.body_mocapid[m.body(self._socket_frame.full_identifier).id],
            socket_geoms=set(np.flatnonzero(m.geom_bodyid == bind(self.socket.body).element_id).tolist()),
        )
        self._nominal_damping = m.dof_damping[self._ids["hand_dof"]].copy()
        # Lookup tables over geom ids for the contact-force filter.
        self._peg_geom_mask = np.zeros(m.ngeom, bool)
        self._peg_geom_mask[list(self._ids["peg_geoms"])] = True
        self._contact_slot = np.full(m.ngeom, -1)
        self._contact_slot[list(self._ids["socket_geoms"])] = 0
        self._contact_slot[self._ids["pad_geoms"]] = (1, 2)

    def initialize_episode(self, physics, random_state):
        cfg, r, ids = self.config, self.config.randomization, self._ids
        m, d = physics.model.ptr, physics.data.ptr

        def sample(low, high):
            # Uniform in [low, high] shrunk about its midpoint by the curriculum's scale (1: the paper's).
            low, high = np.asarray(low, float), np.asarray(high, float)
            mid = 0.5 * (low + high)
            return mid + self.randomization_scale * (random_state.uniform(low, high) - mid) if r.enabled else mid

        # Socket pose (fixed base) and its observation noise, drawn once per episode.
        physics.data.mocap_pos[ids["socket_mocap"]] = sample(r.socket_pos_low, r.socket_pos_high)
        noise = r.socket_obs_noise
        self._socket_noise = sample([-noise] * 3, [noise] * 3)
        # Contact and joint parameter noise.
        stiffness, damping = sample(*r.pad_stiffness), sample(*r.pad_damping)
        # Pad compliance as MuJoCo's (time constant, damping ratio): a stiffer elastomer responds faster.
        physics.model.geom_solref[ids["pad_geoms"]] = (PAD_TIMECONST * np.sqrt(250.0 / stiffness), 1.0 + damping)
        physics.model.dof_damping[ids["hand_dof"]] = self._nominal_damping + sample(*r.joint_damping_noise)
        # Hand pose: fingertip midpoint position and the three hinge angles.
        pos = sample(r.ee_pos_low, r.ee_pos_high)
        roll, pitch, yaw = sample(r.ee_rot_low, r.ee_rot_high)
        qpos = np.concatenate([pos, [yaw, pitch, roll]])
        physics.data.qpos[:] = physics.model.qpos0
        physics.data.qvel[:] = 0.0
        physics.data.qpos[ids["hand_qpos"]] = qpos
        physics.data.ctrl[ids["hand_act"]] = qpos
        # Peg in the hand: its bottom `depth` below the fingertips, tilted about the closing axis
        # around the middle of the grasped segment.
        depth, tilt = sample(*r.peg_in_hand_depth), sample(*r.peg_in_hand_tilt)
        pivot = np.array([0.0, 0.0, -0.5 * (self.peg_geometry.length - depth)])
        tilt_rot = matrix_from_euler_zyx(0.0, tilt, 0.0)
        peg_rot_hand = tilt_rot @ _DOWN  # peg z axis points up the hand, away from the fingertips
        peg_pos_hand = pivot + tilt_rot @ (np.array([0.0, 0.0, depth]) - pivot)
        hand_rot = _DOWN @ matrix_from_euler_zyx(yaw, pitch, roll)
        peg_pos = pos + hand_rot @ peg_pos_hand
        peg_quat = np.empty(4)
        mujoco.mju_mat2Quat(peg_quat, (hand_rot @ peg_rot_hand).ravel())
        physics.data.qpos[ids["peg_qpos"]:ids["peg_qpos"] + 7] = np.concatenate([peg_pos, peg_quat])
        # Close the fingers on the peg with gravity off, as TacSL does, then turn gravity back on.
        half_grip = self.peg_geometry.half_y if cfg.peg_shape == "rectangular" else self.peg_geometry.half_x
        physics.data.qpos[ids["finger_qpos"]] = half_grip
        physics.data.ctrl[ids["finger_act"]] = 0.0
        gravity = physics.model.opt.gravity.copy()
        physics.model.opt.gravity[:] = 0.0
        mujoco.mj_forward(m, d)
        for _ in range(int(round(SETTLE_SECONDS / physics.model.opt.timestep))):
            mujoco.mj_step(m, d)
        physics.model.opt.gravity[:] = gravity
        mujoco.mj_forward(m, d)
        self._step = 0
        self._prev_action = np.zeros(6)
        self.first_success_step = -1
        self._f_ref[:] = 0.0
        self._cache.clear()
        if cfg.tactile_residual:  # paper eq. 2: residual against the field recorded at grasp
            self._f_ref[:] = self.raw_tactiles(physics)

    def before_step(self, physics, action, random_state):
        action = np.clip(np.asarray(action, float), -1.0, 1.0)
        target = hand_target(physics.data.qpos[self._ids["hand_qpos"]], action, self.config.pos_action_scale,
                             self.config.rot_action_scale)
        physics.data.ctrl[self._ids["hand_act"]] = target
        change = action - self._prev_action
        self._action_delta = math.sqrt(change @ change)
        self._prev_action = action

    def after_step(self, physics, random_state):
        self._step += 1
        if self.first_success_step < 0 and self.is_success(physics):
            self.first_success_step = self._step

    def should_terminate_episode(self, physics):
        return self._step >= self.config.episode_steps

    def get_discount(self, physics):
        return 1.0  # TacSL ends episodes by time-out only: always a truncation

    def get_reward(self, physics):
        cfg = self.config
        distance = self.keypoint_distance(physics)
        kp = -distance
        offset, height = self.peg_offset(physics)
        centred = offset < self.peg_geometry.half_x
        if cfg.use_shaped_keypoint_reward and not centred and height < props.HOLE_DEPTH:  # beside the hole, below its top
            kp *= 10.0
        # TacSL's 1 / (exp(-50 d) + 1e-4 + exp(50 d)), multiplied through by exp(-50 d) <= 1 (d >= 0): the same
        # value without overflowing when the peg ends far away (a knocked-off or diverged peg).
        decay = math.exp(-50.0 * distance)
        kp_exp = decay / (decay * decay + 0.0001 * decay + 1.0)
        reward = cfg.keypoint_reward_scale * (kp + kp_exp) - cfg.action_gradient_penalty_scale * self._action_delta
        reward += cfg.success_reward_scale * float(self.is_success(physics))
        return reward - cfg.lateral_reward_scale * offset

    # ------------------------------------------------------------------------------------ task state
    def socket_pos(self, physics) -> np.ndarray:
        return physics.data.mocap_pos[self._ids["socket_mocap"]].copy()

    @staticmethod
    def _state_key(physics) -> tuple:
        data = physics.data.ptr  # MuJoCo's own MjData: cheaper attribute access than dm_control's wrapper
        return data.time, data.qpos.tobytes()

    def _per_state(self, name: str, physics, compute):
        """compute(), memoised for the current physics state (several observables and the reward share it)."""
        key = self._state_key(physics)
        hit = self._cache.get(name)
        if hit is None or hit[0] != key:
            hit = self._cache[name] = (key, compute())
        return hit[1]

    def keypoint_distance(self, physics) -> float:
        """Mean distance between the peg's and the goal's keypoints along their z axes."""
        return self._per_state("keypoint_distance", physics, lambda: self._keypoint_distance(physics))

    def _keypoint_distance(self, physics) -> float:
        d, peg = physics.data, self._ids["peg_body"]
        return mean_keypoint_distance(d.xpos[peg], d.xmat[peg], self.socket_pos(physics), self._keypoints)

    def is_success(self, physics) -> bool:
        return self.keypoint_distance(physics) < self.config.success_threshold

    def peg_offset(self, physics) -> tuple[float, float]:
        """The peg's bottom-face centre relative to the goal: horizontal distance from the hole axis and height
        above the hole floor (m)."""
        delta = physics.data.xpos[self._ids["peg_body"]] - self.socket_pos(physics)
        return math.hypot(delta[0], delta[1]), float(delta[2])

    def outcome(self, physics) -> dict:
        """Where the peg is relative to the goal (`peg_offset`, and its tilt, rad) and what that means, for
        reading why episodes fail."""
        offset, height = self.peg_offset(physics)
        tilt = float(np.arccos(min(abs(physics.data.xmat[self._ids["peg_body"]][8]), 1.0)))
        if self.is_success(physics):
            label = "inserted"
        elif tilt > np.pi / 4:
            label = "dropped or knocked over"
        elif offset > self.socket.outer_half_width:
            label = "not over the socket"
        elif height < 0.002:
            label = "at the bottom, misaligned"
        elif height < props.HOLE_DEPTH - 0.001 and offset < 0.002:  # inside the hole, not pressed into its rim
            label = "stuck part-way in the hole"
        else:
            label = "on or above the socket"
        return dict(outcome=label, peg_offset_xy=offset, peg_height=height, peg_tilt=tilt)

    @property
    def step_count(self) -> int:
        return self._step

    def get_state(self, physics) -> dict:
        """Task state beyond qpos/qvel, for exact resume: episode bookkeeping and the model fields and
        socket pose this episode randomized."""
        ids = self._ids
        return dict(step=self._step, prev_action=self._prev_action.copy(), socket_noise=self._socket_noise.copy(),
                    randomization_scale=self.randomization_scale,
                    f_ref=self._f_ref.copy(), first_success_step=self.first_success_step,
                    action_delta=self._action_delta, mocap_pos=physics.data.mocap_pos.copy(),
                    pad_solref=physics.model.geom_solref[ids["pad_geoms"]].copy(),
                    dof_damping=physics.model.dof_damping[ids["hand_dof"]].copy(),
                    # The last substep's solve cannot be recomputed from the state: keep it, with its state key.
                    contact_forces=self._cache.get("contact_forces"))

    def set_state(self, physics, state: dict) -> None:
        """Restore `get_state`; call before setting qpos/qvel and running a forward pass."""
        ids = self._ids
        physics.model.geom_solref[ids["pad_geoms"]] = state["pad_solref"]
        physics.model.dof_damping[ids["hand_dof"]] = state["dof_damping"]
        physics.data.mocap_pos[:] = state["mocap_pos"]
        self._cache.clear()
        if state.get("contact_forces") is not None:  # absent from checkpoints written before it was kept
            self._cache["contact_forces"] = state["contact_forces"]
        self._step = state["step"]
        self.randomization_scale = state["randomization_scale"]
        self._prev_action = state["prev_action"].copy()
        self._socket_noise = state["socket_noise"].copy()
        self._f_ref = state["f_ref"].copy()
        self.first_success_step = state["first_success_step"]
        self._action_delta = state["action_delta"]

    # ---------------------------------------------------------------------------------- observations
    def _velocity(self, physics, obj_type, obj_id):
        res = np.empty(6)
        mujoco.mj_objectVelocity(physics.model.ptr, physics.data.ptr, obj_type, obj_id, res, 0)
        return res[3:], res[:3]  # linear, angular (world frame)

    def raw_tactiles(self, physics) -> np.ndarray:
        """Force fields of both pads (2, 3, rows, cols) before the grasp reference is subtracted."""
        return self._per_state("tactile", physics, lambda: self._raw_tactiles(physics))

    def _raw_tactiles(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        sites, peg = ids["pad_sites"], ids["peg_body"]
        velocities = [self._velocity(physics, mujoco.mjtObj.mjOBJ_SITE, site) for site in sites]
        peg_lin, peg_ang = self._velocity(physics, mujoco.mjtObj.mjOBJ_BODY, peg)
        return self.tactile.fields(self.peg_geometry, d.site_xpos[sites], d.site_xmat[sites].reshape(-1, 3, 3),
                                   np.array([v[0] for v in velocities]), np.array([v[1] for v in velocities]),
                                   d.xpos[peg], d.xmat[peg].reshape(3, 3), peg_lin, peg_ang)

    def raw_tactile(self, physics, side: int) -> np.ndarray:
        """Force field of one pad (0 left, 1 right) before the grasp reference is subtracted."""
        return self.raw_tactiles(physics)[side]

    def tactile_field(self, physics, side: int) -> np.ndarray:
        """Residual force field of one pad (paper eq. 2), float32 (3, rows, cols)."""
        return (self.raw_tactile(physics, side) - self._f_ref[side]).astype(np.float32)

    def contact_forces(self, physics) -> np.ndarray:
        """World-frame forces on the peg from the socket, the left pad and the right pad (9,): those of the
        control step's last substep (`step_physics`), or, where no substep has run yet, solved for this state."""
        return self._per_state("contact_forces", physics, lambda: self._contact_forces(physics))

    def _contact_forces(self, physics) -> np.ndarray:
        d, m = physics.data, physics.model
        # The state ends with mj_step1: the contact list is new but efc_force still belongs to the previous
        # contacts (stale or uninitialised rows). Solve the constraint forces for this state.
        mujoco.mj_forwardSkip(m.ptr, d.ptr, mujoco.mjtStage.mjSTAGE_VEL, 0)
        return self._solved_contact_forces(d.ptr)

    def _solved_contact_forces(self, data) -> np.ndarray:
        """The peg's contact forces from MjData whose contact list and efc_force belong to one solve."""
        con = data.contact
        out = _peg_contact_forces(con.geom, con.efc_address, con.dim, con.frame, data.efc_force,
                                  self._peg_geom_mask, self._contact_slot)
        return out.ravel().astype(np.float32)

    def step_physics(self, physics, substeps: int) -> None:
        """`substeps` physics steps as dm_control's Physics.step takes them (mj_step2 first and mj_step1 last,
        so positions and velocities stay current; its invalid-state check too), keeping the contact forces of
        the last substep's constraint solve for the contact-force observation. Those are the forces MuJoCo
        applied over the last substep, as Isaac Gym reports net contact forces after a step; solving again
        for the final state would cost a constraint solve per control step (docs/benchmarks.md)."""
        # dm_control's path for the arena's (non-RK4) integrator.
        m, d = physics.model.ptr, physics.data.ptr
        with physics.check_invalid_state():
            mujoco.mj_step2(m, d)  # ends the substep whose mj_step1 ended the previous call
            if substeps > 1:
                if substeps > 2:
                    mujoco.mj_step(m, d, substeps - 2)
                mujoco.mj_step1(m, d)
                mujoco.mj_step2(m, d)
            forces = self._solved_contact_forces(d) if self._observes_contact_forces else None
            mujoco.mj_step1(m, d)
        if forces is not None:
            self._cache["contact_forces"] = (self._state_key(physics), forces)

    def render_wrist(self, physics) -> np.ndarray:
        """64x64 RGB uint8 (H, W, 3) from one persistent renderer (dm_control rebuilds a scene per frame)."""
        if self._renderer is None:
            size = self.config.camera_size
            self._renderer = mujoco.Renderer(physics.model.ptr, size, size)
            self._scene_option = mujoco.MjvOption()
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
            self._renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
            self._camera_id = physics.model.camera("gripper/wrist").id
        self._renderer.update_scene(physics.data.ptr, self._camera_id, self._scene_option)
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def observed_socket_pos(self, physics) -> np.ndarray:
        """The socket position the actor sees: the true one plus this episode's noise."""
        return self.socket_pos(physics) + self._socket_noise

    # Each vector observation ends with the offset to the (observed) socket that it implies. It adds no
    # information, but normalized absolute positions spread over 20 cm leave a millimetre offset at 0.02
    # standard deviations, which a network needs many updates to learn to cancel (docs/environment.md).
    def proprio(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        socket_quat = np.array([1.0, 0, 0, 0])
        tcp, socket = d.site_xpos[ids["tcp"]], self.observed_socket_pos(physics)
        return np.concatenate([tcp, d.xquat[ids["hand_body"]], socket, socket_quat,
                               d.qpos[ids["finger_qpos"]], socket - tcp]).astype(np.float32)

    def peg_state(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        peg = d.xpos[ids["peg_body"]]
        return np.concatenate([peg, d.xquat[ids["peg_body"]], self.observed_socket_pos(physics) - peg]).astype(np.float32)

    def critic_state(self, physics) -> np.ndarray:
        ids, d = self._ids, physics.data
        lin, ang = self._velocity(physics, mujoco.mjtObj.mjOBJ_SITE, ids["tcp"])
        peg, socket = d.xpos[ids["peg_body"]], self.socket_pos(physics)
        return np.concatenate([
            d.site_xpos[ids["tcp"]], d.xquat[ids["hand_body"]], peg, d.xquat[ids["peg_body"]],
            socket, [1.0, 0, 0, 0], d.qpos[ids["finger_qpos"]], lin, ang,
            self.contact_forces(physics), socket - peg, [self.keypoint_distance(physics)]]).astype(np.float32)

    def observe(self, physics) -> dict:
        """The enabled observations computed now from physics (with actuation, unlike composer's reset)."""
        return {name: np.asarray(self._sources[name](physics)) for name in self.config.observations}

    def _build_observables(self):
        sources = dict(
            proprio=self.proprio, peg_state=self.peg_state, contact_forces=self.contact_forces,
            critic_state=self.critic_state,
            wrist=lambda physics: np.ascontiguousarray(self.render_wrist(physics).transpose(2, 0, 1)),
            tactile_left=lambda physics: self.tactile_field(physics, 0),
            tactile_right=lambda physics: self.tactile_field(physics, 1),
        )
        self._sources = sources
        self._observables = {}
        for name, fn in sources.items():
            obs = observable.Generic(fn)
            obs.enabled = name in self.config.observations
            self._observables[name] = obs


class InsertionEnvironment(composer.Environment):
    """composer's Environment with a leaner control step: the physics substeps in one call (the task's
    `step_physics`, MuJoCo's own loop) and the observation computed once, by the task, after them.

    Between substeps composer calls the substep hooks and the observation updater. This task and its entities
    have no substep hooks, and each observable keeps one value taken after the last substep (no delay, no
    buffer), so the trajectory and the observations are composer's own bit for bit (tested; the contact
    forces apart, which this step takes from the last substep's solve), without eight Python round trips
    through composer and dm_control per control step (docs/benchmarks.md). Reset, specs and the step's hooks,
    reward, discount, time limit and physics-error handling are composer's (dm-control 1.0.50).
    """

    def __init__(self, task: InsertionTask, **kwargs):
        substep_hooks = [f"{type(owner).__name__}.{hook}" for owner, base in
                         [(task, composer.Task)] + [(e, composer.Entity) for e in task.root_entity.iter_entities()]
                         for hook in ("before_substep", "after_substep")
                         if getattr(type(owner), hook) is not getattr(base, hook)]
        sampled = [name for name, obs in task.observables.items()
                   if obs.update_interval != 1 or obs.buffer_size not in (None, 1) or obs.delay not in (None, 0)
                   or obs.aggregator is not None or obs.corruptor is not None]
        if substep_hooks or sampled:
            raise ValueError(f"{type(self).__name__} steps the physics substeps in one call: it cannot run substep "
                             f"hooks {substep_hooks} or buffer, delay or transform observables {sampled}")
        super().__init__(task, **kwargs)

    def add_extra_hook(self, hook_name, hook_callable):
        if hook_name in ("before_substep", "after_substep"):
            raise ValueError(f"hook_name={hook_name!r} is not allowed: {type(self).__name__} steps the physics "
                             "substeps in one call")
        super().add_extra_hook(hook_name, hook_callable)

    def step(self, action) -> dm_env.TimeStep:
        if self._reset_next_step:
            self._reset_next_step = False
            return self.reset()
        physics = self._physics_proxy
        self._hooks.before_step(physics, action, self._random_state)
        try:
            self._task.step_physics(self._physics, self._n_sub_steps)
            diverged = False
        except control.PhysicsError as error:
            if self._raise_exception_on_physics_error:
                raise
            logging.warning(error)
            diverged = True
        self._hooks.after_step(physics, self._random_state)
        if diverged:
            reward, discount, last = 0.0, 0.0, True
        else:
            reward, discount = self._task.get_reward(physics), self._task.get_discount(physics)
            last = self._task.should_terminate_episode(physics) or self._physics.time() >= self._time_limit
        self._reset_next_step = last
        return dm_env.TimeStep(dm_env.StepType.LAST if last else dm_env.StepType.MID, reward, discount,
                               self._task.observe(physics))


def build_environment(config: InsertionConfig, seed: int | None = None,
                      offscreen_size: int | None = None) -> composer.Environment:
    """A composer Environment whose episodes last `episode_steps` control steps."""
    task = InsertionTask(config, offscreen_size=offscreen_size)
    # The task randomizes model fields in place and never edits the MJCF: recompiling it at every reset (composer's
    # default) would only cost ~25 ms an episode. A diverged simulation (rare: a peg wedged between stiff contacts)
    # ends its episode as a termination with reward 0, which the adapter reports, instead of killing a long run.
    return InsertionEnvironment(task, random_state=seed, time_limit=float("inf"), strip_singleton_obs_buffer_dim=True,
                                raise_exception_on_physics_error=False, recompile_mjcf_every_episode=False)
