"""A part grasped by the gripper and brought to a fixed part: the composer Task every task here builds on.

The base owns the shared robot and sensors (arena, gripper, tactile pads, wrist camera, contact forces), the
hand's impedance control, the grasp settle, the lean physics step, state save/restore and the observables.
A task adds its two parts (`_build_parts`), its episode start (`initialize_episode`), reward, success and
outcome, and its vector observations (`_observation_sources`); its config declares every observation once.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
from dm_control import composer
from dm_control.composer.observation import observable
from dm_env import specs

from vitac.sim.arena import Arena
from vitac.sim.balance import ForceBalance, step_asymmetries
from vitac.sim.contact import part_contact_forces
from vitac.sim.gripper import PAD_LENGTH, PAD_WIDTH, ParallelGripper
from vitac.sim.poses import hand_target
from vitac.sim.tactile import TactileFieldSensor
from vitac.tasks.config import GraspTaskConfig

PAD_TIMECONST = 0.01  # pad contact time constant (s) at the nominal stiffness 250
SETTLE_SECONDS = 0.25  # TacSL closes the gripper for 30 sim steps of 1/120 s with gravity off


class GraspedPartTask(composer.Task):
    """Bring a part held between the two sensing pads to a fixed part.

    Subclasses set `self.held` (an entity with a `body`, every geom of which is the part), `self.held_shape` (a
    `vitac.sim.tactile.ContactShape`: the part as the pads feel it) and `self.fixed` (an entity with `body`) through `_attach_parts` in
    `_build_parts`, and implement `initialize_episode` (ending with `_settle_grasp`), `get_reward`,
    `keypoint_distance`, `is_success`, `outcome` and `_observation_sources`.

    Args:
        config: validated task settings.
        offscreen_size: offscreen render buffer (pixels); the camera size unless a tool renders larger views.
    """

    def __init__(self, config: GraspTaskConfig, offscreen_size: int | None = None):
        self.config = config
        self._arena = Arena(offscreen_size=offscreen_size or config.camera_size,
                            noslip_iterations=config.noslip_iterations)
        self.gripper = ParallelGripper(
            hand_mass=config.hand_mass, hand_inertia=config.hand_inertia, prop_gains=config.prop_gains,
            deriv_gains=config.deriv_gains, joint_damping=config.joint_damping, finger_kp=config.finger_kp,
            finger_kd=config.finger_kd, pad_friction=config.pad_friction, camera_fovy=config.camera_fovy)
        self._arena.attach(self.gripper)
        self._build_parts()
        self.set_timesteps(control_timestep=1.0 / config.control_hz,
                           physics_timestep=1.0 / (config.control_hz * config.physics_substeps))
        self.tactile = TactileFieldSensor(config.taxel_rows, config.taxel_cols, PAD_WIDTH, PAD_LENGTH,
                                          config.taxel_margin, config.tactile_kn, config.tactile_kt, config.tactile_mu)
        self._renderer = None
        self.randomization_scale = config.randomization.scale
        self._cache: dict = {}  # per-physics-state values: tactile fields, contact forces, keypoint distance
        specs_ = config.observation_specs()
        self._observes_contact_forces = any(specs_[name].needs_contact_forces for name in config.observations)
        self._ids = None
        self._step = 0
        self._prev_action = np.zeros(6)
        self._action_delta = 0.0
        self._f_ref = np.zeros((2, 3, config.taxel_rows, config.taxel_cols))
        self.first_success_step = -1
        self.episode_factors: dict = {}  # this episode's randomized values, by factor name (evaluation reports)
        self.force_balance = ForceBalance()  # filled where config.measure_force_balance (evaluation reports)
        self._build_observables()

    def _build_parts(self) -> None:
        raise NotImplementedError

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
            link_geoms=[bind(g).element_id for g in self.gripper.links],
            held_body=bind(self.held.body).element_id,
            held_geoms=set(np.flatnonzero(m.geom_bodyid == bind(self.held.body).element_id).tolist()),
            held_qpos=m.jnt_qposadr[m.body_jntadr[bind(self._held_frame).element_id]],
            # bind() does not accept mocap bodies: look the frame up by name.
            fixed_mocap=m.body_mocapid[m.body(self._fixed_frame.full_identifier).id],
            fixed_geoms=set(np.flatnonzero(m.geom_bodyid == bind(self.fixed.body).element_id).tolist()),
        )
        self._nominal_damping = m.dof_damping[self._ids["hand_dof"]].copy()
        # Lookup tables over geom ids for the contact-force filter.
        self._held_geom_mask = np.zeros(m.ngeom, bool)
        self._held_geom_mask[list(self._ids["held_geoms"])] = True
        self._contact_slot = np.full(m.ngeom, -1)
        self._contact_slot[list(self._ids["fixed_geoms"])] = 0
        self._contact_slot[self._ids["pad_geoms"]] = (1, 2)

    def _attach_parts(self, held: composer.Entity, fixed: composer.Entity) -> None:
        """Add the held part on a free joint and the fixed part on a mocap body (in that order: ids follow it)."""
        self.held, self.fixed = held, fixed
        self._held_frame = self._arena.add_free_entity(held)  # the body carrying the part's free joint
        self._fixed_frame = self._arena.attach(fixed)
        # A mocap body: MuJoCo expects moved static bodies to be mocap (moving body_pos of a static body
        # at run time silently breaks collision detection elsewhere in the scene).
        self._fixed_frame.mocap = "true"

    # ------------------------------------------------------------------------------- episode helpers
    def _draw(self, random_state, name: str, low, high) -> np.ndarray:
        """Uniform in [low, high] shrunk about its midpoint by the curriculum's scale (1: the full range), or the
        midpoint with randomization off; kept as `episode_factors[name]` so that a report can group failures by it."""
        low, high = np.asarray(low, float), np.asarray(high, float)
        mid = 0.5 * (low + high)
        value = mid + self.randomization_scale * (random_state.uniform(low, high) - mid) \
            if self.config.randomization.enabled else mid
        self.episode_factors[name] = value.tolist()
        return value

    def _set_pad_compliance(self, physics, stiffness: float, damping: float) -> None:
        """Pad compliance as MuJoCo's (time constant, damping ratio): a stiffer elastomer responds faster."""
        physics.model.geom_solref[self._ids["pad_geoms"]] = (PAD_TIMECONST * np.sqrt(250.0 / stiffness), 1.0 + damping)

    def _settle_grasp(self, physics, half_grip: float) -> None:
        """Close the fingers on the held part with gravity off, as TacSL does, then turn gravity back on;
        then start the episode's bookkeeping and record the pads' grasp reference (paper eq. 2)."""
        ids, m, d = self._ids, physics.model.ptr, physics.data.ptr
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
        self.force_balance.reset()
        if self.config.tactile_residual:  # paper eq. 2: residual against the field recorded at grasp
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
        if self.config.measure_force_balance:
            touching = bool(np.any(self.contact_forces(physics)[:3]))  # the fixed part pushes on the held one
            self.force_balance.add(self.pad_asymmetries(physics), touching)
        if self.first_success_step < 0 and self.is_success(physics):
            self.first_success_step = self._step

    def should_terminate_episode(self, physics):
        return self._step >= self.config.episode_steps

    def get_discount(self, physics):
        return 1.0  # TacSL ends episodes by time-out only: always a truncation

    def keypoint_distance(self, physics) -> float:
        """Distance (m) between the held part's keypoints and their goal: what success and reward read."""
        raise NotImplementedError

    def is_success(self, physics) -> bool:
        raise NotImplementedError

    def outcome(self, physics) -> dict:
        """How an episode ended, for evaluation reports: `outcome` (a label) and any numbers (SI units)."""
        raise NotImplementedError

    @property
    def step_count(self) -> int:
        return self._step

    # ------------------------------------------------------------------------------------ task state
    def fingers_on_fixed_part(self, physics) -> int:
        """How many finger links (0-2) touch the fixed part now: a hand resting on it cannot push the part further."""
        d, ids = physics.data.ptr, self._ids
        touching = set()
        for g1, g2 in d.contact.geom[:d.ncon]:
            for link, other in ((g1, g2), (g2, g1)):
                if link in ids["link_geoms"] and other in ids["fixed_geoms"]:
                    touching.add(link)
        return len(touching)

    def fixed_pos(self, physics) -> np.ndarray:
        return physics.data.mocap_pos[self._ids["fixed_mocap"]].copy()

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

    def get_state(self, physics) -> dict:
        """Task state beyond qpos/qvel, for exact resume: episode bookkeeping and the model fields and
        fixed-part pose this episode randomized."""
        ids = self._ids
        return dict(step=self._step, prev_action=self._prev_action.copy(),
                    randomization_scale=self.randomization_scale,
                    f_ref=self._f_ref.copy(), first_success_step=self.first_success_step,
                    action_delta=self._action_delta, mocap_pos=physics.data.mocap_pos.copy(),
                    episode_factors=dict(self.episode_factors), force_balance=self.force_balance.state(),
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
        self._f_ref = state["f_ref"].copy()
        self.first_success_step = state["first_success_step"]
        self._action_delta = state["action_delta"]
        self.episode_factors = dict(state.get("episode_factors", {}))  # absent from older checkpoints
        if "force_balance" in state:  # likewise
            self.force_balance.load_state(state["force_balance"])

    # --------------------------------------------------------------------------------------- sensors
    def _velocity(self, physics, obj_type, obj_id):
        res = np.empty(6)
        mujoco.mj_objectVelocity(physics.model.ptr, physics.data.ptr, obj_type, obj_id, res, 0)
        return res[3:], res[:3]  # linear, angular (world frame)

    def raw_tactiles(self, physics) -> np.ndarray:
        """Force fields of both pads (2, 3, rows, cols) before the grasp reference is subtracted."""
        return self._per_state("tactile", physics, lambda: self._raw_tactiles(physics))

    def _raw_tactiles(self, physics) -> np.ndarray:
        # MuJoCo's own MjModel/MjData: dm_control's wrappers cost more than the force kernel here.
        ids, m, d = self._ids, physics.model.ptr, physics.data.ptr
        sites, held = ids["pad_sites"], ids["held_body"]
        velocity = np.empty((len(sites) + 1, 6))  # (angular, linear) of each pad site, then of the held part
        for row, site in enumerate(sites):
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, site, velocity[row], 0)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, held, velocity[-1], 0)
        return self.tactile.fields(self.held_shape, d.site_xpos[sites], d.site_xmat[sites].reshape(-1, 3, 3),
                                   velocity[:-1, 3:], velocity[:-1, :3], d.xpos[held], d.xmat[held].reshape(3, 3),
                                   velocity[-1, 3:], velocity[-1, :3])

    def raw_tactile(self, physics, side: int) -> np.ndarray:
        """Force field of one pad (0 left, 1 right) before the grasp reference is subtracted."""
        return self.raw_tactiles(physics)[side]

    def tactile_field(self, physics, side: int) -> np.ndarray:
        """Residual force field of one pad (paper eq. 2), float32 (3, rows, cols)."""
        return (self.raw_tactile(physics, side) - self._f_ref[side]).astype(np.float32)

    def balance_penalty(self, physics) -> float:
        """`balance_penalty_scale` times this step's field asymmetry between the pads (0 where neither feels
        anything), for the task's reward."""
        scale = self.config.balance_penalty_scale
        return scale * (self.pad_asymmetries(physics)["field"] or 0.0) if scale else 0.0

    def pad_asymmetries(self, physics) -> dict:
        """This state's field and net-force asymmetries between the pads (vitac/sim/balance.py), memoised: the
        force-balance measure and the reward's penalty both read them."""
        return self._per_state("pad_asymmetries", physics, lambda: step_asymmetries(
            self.tactile_field(physics, 0), self.tactile_field(physics, 1)))

    def contact_forces(self, physics) -> np.ndarray:
        """World-frame forces on the held part from the fixed part, the left pad and the right pad (9,): those
        of the control step's last substep (`step_physics`), or, where no substep has run yet, solved for this
        state."""
        return self._per_state("contact_forces", physics, lambda: self._contact_forces(physics))

    def _contact_forces(self, physics) -> np.ndarray:
        d, m = physics.data, physics.model
        # The state ends with mj_step1: the contact list is new but efc_force still belongs to the previous
        # contacts (stale or uninitialised rows). Solve the constraint forces for this state.
        mujoco.mj_forwardSkip(m.ptr, d.ptr, mujoco.mjtStage.mjSTAGE_VEL, 0)
        return self._solved_contact_forces(d.ptr)

    def _solved_contact_forces(self, data) -> np.ndarray:
        """The held part's contact forces from MjData whose contact list and efc_force belong to one solve."""
        con = data.contact
        out = part_contact_forces(con.geom, con.efc_address, con.dim, con.frame, data.efc_force,
                                  self._held_geom_mask, self._contact_slot)
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

    # ---------------------------------------------------------------------------------- observations
    def _observation_sources(self) -> dict:
        """The task's own observations (name -> function of physics), beside the shared sensors'."""
        raise NotImplementedError

    def observe(self, physics) -> dict:
        """The enabled observations computed now from physics (with actuation, unlike composer's reset)."""
        return {name: np.asarray(self._sources[name](physics)) for name in self.config.observations}

    def _build_observables(self):
        sources = dict(
            self._observation_sources(), contact_forces=self.contact_forces,
            wrist=lambda physics: np.ascontiguousarray(self.render_wrist(physics).transpose(2, 0, 1)),
            tactile_left=lambda physics: self.tactile_field(physics, 0),
            tactile_right=lambda physics: self.tactile_field(physics, 1),
        )
        declared = list(self.config.observation_specs())
        if set(sources) != set(declared):
            raise TypeError(f"{type(self).__name__} computes observations {sorted(sources)} but its config declares "
                            f"{sorted(declared)}")
        self._sources = sources = {name: sources[name] for name in declared}
        self._observables = {}
        for name, fn in sources.items():
            obs = observable.Generic(fn)
            obs.enabled = name in self.config.observations
            self._observables[name] = obs
