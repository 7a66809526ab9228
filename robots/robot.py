"""A robot body in a World: URDF multibody (visual), collision probe cylinder, effectors, receptors.
Constructed and driven inside the world's pybullet thread; use RobotAPI from async code."""
from __future__ import annotations

import contextlib
import math
from typing import TYPE_CHECKING

import numpy as np
from .pybullet_quiet import p

from .contact_sensors import ContactSensors
from .depth_camera import DepthCamera
from .effectors import BaseEffector, HeadEffector, JointsEffector
from .failure_modes import Locomotion, defaults_for, make_locomotion
from .frames import pose_matrix, yaw_quat
from .loudspeaker import Loudspeaker
from .odometry import Odometry, OdometryNoise
from .microphones import Microphone
from .multibody import create_bodies, probe_z
from .receptors import Camera, RangeSensor
from .spec import RobotSpec

AHEAD_RAD = 0.52  # "ahead" for the collision protection: readings within ±30° of the heading

if TYPE_CHECKING:
    from .body import Surroundings
    from .controllers import Controller


class Robot:
    """A robot body (robots.body.Body to its parts) in a world (robots.world.World)."""

    def __init__(self, world: Surroundings, spec: RobotSpec, name: str, pose: tuple[float, float, float],
                 noise: OdometryNoise | None, rng: np.random.Generator):
        self.world, self.spec, self.name, self.kind = world, spec, name, spec.kind
        cid = world.cid
        self.uid, self.probe, self.limits = create_bodies(cid, spec, pose)
        self.root_link = p.getBodyInfo(self.uid, physicsClientId=cid)[0].decode()
        self.link_index = {self.root_link: -1}
        self.joint_index: dict[str, int] = {}
        self.joint_parent: dict[str, str] = {}
        self._joint_origin: dict[str, np.ndarray] = {}
        self._link_joint: dict[str, str] = {}
        names_by_index = {-1: self.root_link}
        for i in range(p.getNumJoints(self.uid, physicsClientId=cid)):
            info = p.getJointInfo(self.uid, i, physicsClientId=cid)
            jn, child = info[1].decode(), info[12].decode()
            self.joint_index[jn], self.link_index[child] = i, i
            names_by_index[i] = child
            self.joint_parent[jn] = names_by_index[info[16]]
            self._joint_origin[jn] = pose_matrix(info[14], info[15])
            self._link_joint[child] = jn
        self.q: dict[str, float] = {n: 0.0 for n in self.limits}
        x, y, th = map(float, pose)
        self.pose = (x, y, th)
        self.odometry = Odometry(pose, noise, rng)
        self.base = BaseEffector(self)
        self.joints = JointsEffector(self)
        self.head = HeadEffector(self)
        self.loudspeaker = Loudspeaker(self) if spec.speech else None
        self.cameras = {c.name: Camera(self, c) for c in spec.cameras}
        self.protection_m: float | None = None  # the collision protection's margin (RobotAPI.protect)
        self.sonars = [RangeSensor(self, s) for s in spec.sonars]
        self.laser = RangeSensor(self, spec.laser) if spec.laser else None
        self.depth_cameras = {d.name: DepthCamera(self, d) for d in spec.depth_cameras}
        self.contacts = (ContactSensors(self, spec.bumpers, spec.touch_sensors)
                         if spec.bumpers or spec.touch_sensors else None)
        self.microphone = Microphone()
        self.controllers: dict[str, "Controller"] = {}
        self.locomotion: Locomotion | None = None
        self.set_failure_modes(defaults_for(spec))
        for j, a in spec.postures.get("StandInit", {}).items():
            self.set_joint(j, a)
        self.update_lift()
        self.set_base_pose(*self.pose)

    def set_failure_modes(self, params) -> None:
        """The robot's failure modes (robots/failure_modes.py: NaoFailures / ElektronFailures), or None: an
        ideal robot (exact motion, noise-free sensors, manual exposure). Set it before the robot moves."""
        self.failure_modes = params
        self.locomotion = make_locomotion(self.spec, params, self.world.plan.seed, self.name)
        for cam in self.cameras.values():
            cam.set_noise(getattr(params, "camera", None))
        for sonar in self.sonars:
            sonar.noise = getattr(params, "sonar", None)
        if self.laser is not None:
            self.laser.noise = getattr(params, "laser", None)
        for depth in self.depth_cameras.values():
            depth.set_noise(params is not None)

    # ------------------------------------------------------------ kinematics (pybullet thread)
    def _probe_z(self) -> float:
        return probe_z(self.spec)

    def set_base_pose(self, x: float, y: float, th: float) -> None:
        cid = self.world.cid
        q = yaw_quat(th)
        p.resetBasePositionAndOrientation(self.uid, [x, y, 0.0], q, physicsClientId=cid)
        p.resetBasePositionAndOrientation(self.probe, [x, y, self._probe_z()], q, physicsClientId=cid)
        self.pose = (x, y, th)

    def collides(self, x: float, y: float) -> bool:
        """Would the collision cylinder at (x, y) penetrate a wall, door, furniture, lamp or robot?"""
        cid = self.world.cid
        cands = self.world.obstacles_near(x, y, self.spec.radius + 0.05, exclude=self.probe)
        if not cands:
            return False
        p.resetBasePositionAndOrientation(self.probe, [x, y, self._probe_z()], [0, 0, 0, 1], physicsClientId=cid)
        for uid in cands:
            for pt in p.getClosestPoints(self.probe, uid, 0.0, physicsClientId=cid):
                if pt[8] < -1e-4:
                    return True
        return False

    @contextlib.contextmanager
    def probe_hidden(self):
        """Move the own collision cylinder away (e.g. so the robot's own rays do not hit it)."""
        cid = self.world.cid
        p.resetBasePositionAndOrientation(self.probe, [0, 0, -100], [0, 0, 0, 1], physicsClientId=cid)
        try:
            yield
        finally:
            p.resetBasePositionAndOrientation(self.probe, [self.pose[0], self.pose[1], self._probe_z()],
                                              yaw_quat(self.pose[2]), physicsClientId=cid)

    def set_joint(self, name: str, angle: float) -> None:
        p.resetJointState(self.uid, self.joint_index[name], angle, physicsClientId=self.world.cid)
        self.q[name] = angle

    def update_lift(self) -> None:
        if self.spec.lift_joint and self.spec.lift_height:
            self.set_joint(self.spec.lift_joint, self.spec.lift_height(self.q))

    def front_margin(self) -> float | None:
        """How close the nearest range reading ahead (sonar cones, laser rays within ±30°) is: beyond its
        sensor's minimum range, or beyond the robot's body where the sensor sits behind the body's
        edge (an Elektron's laser is 0.14 m inside its footprint), whichever is less; None without
        range sensors. pybullet thread."""
        margins = []
        for s in self.sonars:
            r, (mx, my, yaw) = s.read(), self.sensor_mount(s.spec.link)
            margins.append(min(r - s.spec.range_min, self._clearance(mx, my, yaw, r)))
        if self.laser is not None:
            ranges, angles = self.laser.scan(), self.laser.angles()
            mx, my, yaw = self.sensor_mount(self.laser.spec.link)
            for r, a in zip(ranges, angles):
                if abs(a) <= AHEAD_RAD:
                    margins.append(min(r - self.laser.spec.range_min, self._clearance(mx, my, yaw + a, r)))
        return min(margins) if margins else None

    def _clearance(self, mx: float, my: float, bearing: float, r: float) -> float:
        return math.hypot(mx + r * math.cos(bearing), my + r * math.sin(bearing)) - self.spec.radius

    def sensor_mount(self, link: str) -> tuple[float, float, float]:
        """Where a sensor link sits in the base frame: x ahead, y left (m), yaw. pybullet thread."""
        T = self.link_pose(link)
        x, y, th = self.pose
        dx, dy = T[0, 3] - x, T[1, 3] - y
        return (math.cos(th) * dx + math.sin(th) * dy, -math.sin(th) * dx + math.cos(th) * dy,
                math.remainder(math.atan2(T[1, 0], T[0, 0]) - th, math.tau))

    def tilt_pivot_z(self) -> float:
        """Height of the torso's roll axis (the hips: a NAO's lift joint), m."""
        lift = self.spec.lift_joint
        return self.q.get(lift, 0.0) if lift else 0.0

    def body_sway(self) -> np.ndarray | None:
        """The 4x4 world transform that the torso's roll toward the stance foot and its bob (a NAO walking
        by steps, robots/failure_modes.py NaoWalk) apply to the upper body now; None when it is upright.
        link_pose and so the robot's own kinematics (get_transform) leave it out: the robot does not know
        its sway; its cameras see from it (receptors.Camera.link_pose)."""
        roll, bob = self.locomotion.tilt() if self.locomotion is not None else (0.0, 0.0)
        if not (roll or bob):
            return None
        x, y, th = self.pose
        # about the heading, by -roll: + roll takes the head to the left
        S = pose_matrix((0.0, 0.0, 0.0), [math.cos(th) * math.sin(-roll / 2), math.sin(th) * math.sin(-roll / 2),
                                          0.0, math.cos(-roll / 2)])
        pivot = np.array([x, y, self.tilt_pivot_z()])
        S[:3, 3] = pivot - S[:3, :3] @ pivot + [0.0, 0.0, bob]
        return S

    def link_pose(self, link: str) -> np.ndarray:
        cid = self.world.cid
        idx = self.link_index[link]
        if idx < 0:
            pos, orn = p.getBasePositionAndOrientation(self.uid, physicsClientId=cid)
        else:
            st = p.getLinkState(self.uid, idx, computeForwardKinematics=True, physicsClientId=cid)
            pos, orn = st[4], st[5]
        return pose_matrix(pos, orn)

    def joint_offset(self, joint: str) -> np.ndarray:
        """Fixed transform parent link frame -> joint frame (at joint angle 0)."""
        return self._joint_origin[joint].copy()

    def joint_offset_of_link(self, link: str) -> np.ndarray:
        return self.joint_offset(self._link_joint[link])

    def link_of_joint(self, joint: str) -> str:
        """The link that joint `joint` moves."""
        return next(link for link, jn in self._link_joint.items() if jn == joint)

    def base_in_world(self) -> np.ndarray:
        return self.link_pose(self.root_link)

    def in_base(self, T_world: np.ndarray) -> np.ndarray:
        return np.linalg.inv(self.base_in_world()) @ T_world
