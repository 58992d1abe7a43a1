"""Floating parallel-jaw hand with two tactile pads and a wrist camera.

The hand is a floating body driven by MuJoCo position actuators on three slide and three hinge
joints: each actuator is a joint-space PD (kp, kv), so the hand follows task-space impedance toward a
pose target with TacSL's gains. The hand frame's origin is the fingertip midpoint (TacSL's control
point) and its z axis points from the palm towards the fingertips; fingers close along its y axis.
Hand bodies are gravity-compensated, as TacSL's Franka is.
"""

from __future__ import annotations

import numpy as np
from dm_control import composer, mjcf

from vitac.sim import collision

PAD_WIDTH = 0.024  # GelSight R1.5 elastomer, across the finger (m)
PAD_LENGTH = 0.032  # along the finger (m)
PAD_THICKNESS = 0.004
FINGER_LENGTH = 0.06
FLANGE_TO_TIP = 0.142  # Franka flange to GelSight fingertip midpoint (TacSL URDF)
HAND_JOINTS = ("x", "y", "z", "yaw", "pitch", "roll")


class ParallelGripper(composer.Entity):
    """Floating hand with a left and a right finger, each with a sensing pad.

    Args:
        hand_mass: mass of the moving hand (kg); gives Franka-like reflected inertia.
        hand_inertia: rotational inertia of the hand about each axis (kg m^2).
        prop_gains: task-space stiffness (3 translational N/m, 3 rotational N m/rad).
        deriv_gains: task-space damping (3 translational, 3 rotational).
        joint_damping: passive damping on the six hand joints.
        finger_kp, finger_kd: finger drive gains (TacSL's PhysX gripper PD).
        pad_friction: sliding friction of the pads.
        camera_fovy: wrist camera field of view (deg).
    """

    def _build(self, hand_mass: float, hand_inertia: float, prop_gains, deriv_gains, joint_damping: float,
               finger_kp: float, finger_kd: float, pad_friction: float, camera_fovy: float):
        root = mjcf.RootElement(model="gripper")
        self._mjcf_root = root
        base = root.worldbody.add("body", name="base", gravcomp=1)
        base.add("inertial", pos=(0, 0, 0), mass=0.1 * hand_mass, diaginertia=(1e-4, 1e-4, 1e-4))
        self.joints = []
        for name, axis in zip(HAND_JOINTS[:3], np.eye(3), strict=True):
            self.joints.append(base.add("joint", name=name, type="slide", axis=axis, damping=joint_damping))
        # Pointing down: the hand frame is the base rotated by pi about x; hinges act in the hand frame.
        self.hand = base.add("body", name="hand", quat=(0, 1, 0, 0), gravcomp=1)
        self.hand.add("inertial", pos=(0, 0, 0), mass=hand_mass, diaginertia=(hand_inertia,) * 3)
        for name, axis in zip(HAND_JOINTS[3:], ((0, 0, 1), (0, 1, 0), (1, 0, 0)), strict=True):
            self.joints.append(self.hand.add("joint", name=name, type="hinge", axis=axis, damping=joint_damping))
        link = dict(contype=collision.HAND, conaffinity=collision.HAND_AFFINITY, rgba=(0.9, 0.9, 0.92, 1),
                    density=0)
        palm_z = -FINGER_LENGTH - 0.008
        self.hand.add("geom", name="palm", type="box", size=(0.012, 0.045, 0.008), pos=(0, 0, palm_z), **link)
        self.tcp_site = self.hand.add("site", name="tcp", size=(0.002,), rgba=(1, 0, 0, 0.5))
        self.actuators = []
        for joint, kp, kv in zip(self.joints, prop_gains, deriv_gains, strict=True):
            self.actuators.append(root.actuator.add("position", name=joint.name, joint=joint, kp=kp, kv=kv))
        self.fingers, self.pads, self.pad_sites, self.finger_joints, self.finger_actuators = [], [], [], [], []
        self.links = []  # the finger links behind the pads: they collide with the world
        for side, sign in (("left", 1.0), ("right", -1.0)):
            finger = self.hand.add("body", name=f"{side}_finger", gravcomp=1)
            finger.add("inertial", pos=(0, sign * 0.008, -0.03), mass=0.02, diaginertia=(1e-5, 1e-5, 1e-5))
            joint = finger.add("joint", name=f"{side}_finger", type="slide", axis=(0, sign, 0), range=(0, 0.04),
                               damping=0.0, frictionloss=0.0)
            self.links.append(finger.add("geom", name=f"{side}_link", type="box", size=(0.011, 0.005, 0.5 * FINGER_LENGTH),
                       pos=(0, sign * (PAD_THICKNESS + 0.005), -0.5 * FINGER_LENGTH), **link))
            pad = finger.add("geom", name=f"{side}_pad", type="box",
                             size=(0.5 * PAD_WIDTH, 0.5 * PAD_THICKNESS, 0.5 * PAD_LENGTH),
                             pos=(0, sign * 0.5 * PAD_THICKNESS, -0.5 * PAD_LENGTH),
                             contype=collision.PAD, conaffinity=collision.PAD_AFFINITY,
                             friction=(pad_friction, 0.005, 0.0001), condim=4, priority=2,
                             rgba=(0.15, 0.15, 0.15, 1), density=0)
            # Pad frame: x along image rows, y along image columns (towards the tip), z out of the face.
            # The right pad is the left one turned by pi about the hand's z axis, as on a Franka.
            x_axis = (sign, 0, 0)
            site = finger.add("site", name=f"{side}_pad_frame", pos=(0, 0, -0.5 * PAD_LENGTH),
                              xyaxes=(*x_axis, 0, 0, 1), size=(0.001,), rgba=(0, 0, 0, 0))
            self.finger_actuators.append(root.actuator.add("position", name=f"{side}_finger", joint=joint,
                                                           kp=finger_kp, kv=finger_kd, ctrlrange=(0, 0.04)))
            self.fingers.append(finger)
            self.pads.append(pad)
            self.pad_sites.append(site)
            self.finger_joints.append(joint)
        # TacSL wrist camera: 4.5 cm beside the flange axis, 4 cm below the flange, looking 30 deg off the
        # approach axis towards the fingers (quat [0.5, 0, 0.866, 0] xyzw in Isaac Gym's convention).
        self.camera = self.hand.add("camera", name="wrist", pos=(0.045, 0, -FLANGE_TO_TIP + 0.04),
                                    xyaxes=(0, 1, 0, 0.866, 0, 0.5), fovy=camera_fovy)

    @property
    def mjcf_model(self):
        return self._mjcf_root
