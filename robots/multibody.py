"""A robot's bodies in a PyBullet client: its URDF multibody and the cylinder that probes for collisions.
The World's Robot (robots/robot.py) and the render processes' mirror (robots/render_process.py) build
them with the same code, so both show the same robot."""
from __future__ import annotations

from .frames import yaw_quat
from .pybullet_quiet import p
from .spec import RobotSpec


def probe_z(spec: RobotSpec) -> float:
    """Height of the collision probe's centre: the cylinder stands 2 cm above the floor."""
    return spec.collision_height / 2 + 0.02


def create_bodies(cid: int, spec: RobotSpec, pose: tuple[float, float, float], collision: bool = True
                  ) -> tuple[int, int, dict[str, tuple[float, float]]]:
    """The robot's URDF multibody and its collision-probe cylinder (with a tiny visual marker) at `pose`;
    `collision` False: the probe has no collision shape (a mirror for rendering). Returns (uid, probe
    uid, joint limits)."""
    urdf, limits = spec.build_urdf()
    uid = p.loadURDF(str(urdf), [pose[0], pose[1], 0.0], yaw_quat(pose[2]), useFixedBase=True, physicsClientId=cid)
    col = p.createCollisionShape(p.GEOM_CYLINDER, radius=spec.radius, height=spec.collision_height,
                                 physicsClientId=cid) if collision else -1
    vis = p.createVisualShape(p.GEOM_SPHERE, radius=0.001, rgbaColor=[0, 0, 0, 1], physicsClientId=cid)
    probe = p.createMultiBody(0, col, vis, [pose[0], pose[1], probe_z(spec)], physicsClientId=cid)
    return uid, probe, limits
