"""The static scene of a house in a PyBullet client: floor and ceiling, walls, furniture, doors, lamps,
rugs and QR panels. The World (robots/world.py) builds it in its pybullet thread; each render process
(robots/render_process.py) builds the same scene with the same code in its own client to mirror it."""
from __future__ import annotations

import math

from .errors import InvalidArgument
from .floorplan import CEILING_COLOR, DOOR_COLOR, DOOR_HEIGHT, DOOR_THICKNESS, FLOOR_COLOR, Box, Plan
from .frames import yaw_quat
from .lighting import LAMP_OFF_COLOR, LAMP_ON_COLOR, lamp_radiance, window_radiance
from .pybullet_quiet import p
from .qr import qr_texture, symbol_fraction

PRINT_OFFSET_M = 0.0025  # QR print in front of the wall point the landmark map gives


class Scene:
    """The static bodies of a house, its doors and lamps in client `cid`; World and the render processes'
    MirrorScene subclass it (`_init_scene`, connect, `_build_scene`)."""

    plan: Plan
    cid: int

    def _init_scene(self, plan: Plan) -> None:
        self.plan = plan
        self.cid = -1
        self.emissive: dict[int, tuple[float, float, float]] = {}  # body uid -> radiance: lit shades, windows by day
        self.window_uids: list[int] = []
        self.door_uids: dict[str, int] = {}
        self.lamp_uids: dict[str, tuple[int, int]] = {}

    def _add_obstacle(self, uid: int) -> None:  # World overrides: collision bookkeeping
        pass

    def _box_body(self, b: Box, collision: bool = True, visual: bool = True) -> int:
        cid = self.cid
        half = [b.sx / 2, b.sy / 2, b.sz / 2]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid) if collision else -1
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[*b.color, 1], physicsClientId=cid) if visual else -1
        return p.createMultiBody(0, col, vis, [b.x, b.y, b.z0 + b.sz / 2], yaw_quat(b.yaw), physicsClientId=cid)

    def _build_scene(self) -> None:
        """Create every static body (self.cid must be connected)."""
        plan = self.plan
        x0, y0, x1, y1 = plan.bounds
        cx, cy, sx, sy = (x0 + x1) / 2, (y0 + y1) / 2, x1 - x0 + 1.0, y1 - y0 + 1.0
        self._box_body(Box("floor", cx, cy, sx, sy, 0.02, 0, -0.02, FLOOR_COLOR), collision=False)
        self._box_body(Box("ceiling", cx, cy, sx, sy, 0.02, 0, plan.wall_height, CEILING_COLOR), collision=False)
        for b in plan.walls + plan.furniture:
            self._add_obstacle(self._box_body(b))
        for d in plan.doors:
            self.door_uids[d.id] = uid = self._door_body(d)
            self._add_obstacle(uid)
        for lamp in plan.lamps:
            self.lamp_uids[lamp.id] = self._lamp_bodies(lamp)
            self._add_obstacle(self.lamp_uids[lamp.id][0])
            self._set_lamp(lamp.id, lamp.on)
        for m in plan.landmarks:
            self._landmark_body(m)
        for rug in plan.rugs:  # seen by the camera, felt by the feet only (Plan.slip_at)
            self._box_body(rug, collision=False)
        for pane in plan.windows if plan.sky is not None else ():  # in the wall's line: no collision
            uid = self._box_body(pane, collision=False)
            self.window_uids.append(uid)
            glow = window_radiance(plan.sky)
            if glow is not None:
                self.emissive[uid] = glow

    def _door_body(self, d) -> int:
        cid = self.cid
        w = d.width - 0.02
        half = [w / 2, DOOR_THICKNESS / 2, DOOR_HEIGHT / 2]
        off = [0.01 + w / 2, 0.0, DOOR_HEIGHT / 2]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, collisionFramePosition=off, physicsClientId=cid)
        hx = 0.01 + w - 0.09
        vis = p.createVisualShapeArray(
            shapeTypes=[p.GEOM_BOX, p.GEOM_BOX],
            halfExtents=[half, [0.05, DOOR_THICKNESS / 2 + 0.025, 0.012]],
            visualFramePositions=[off, [hx, 0.0, 1.0]],
            rgbaColors=[[*DOOR_COLOR, 1], [0.85, 0.8, 0.3, 1]], physicsClientId=cid)
        post = p.createVisualShape(p.GEOM_CYLINDER, radius=0.012, length=DOOR_HEIGHT,
                                   visualFramePosition=[0, 0, DOOR_HEIGHT / 2], rgbaColor=[0.3, 0.2, 0.1, 1],
                                   physicsClientId=cid)
        uid = p.createMultiBody(0, -1, post, [d.hinge[0], d.hinge[1], 0.0], yaw_quat(d.closed_yaw),
                                linkMasses=[0.0], linkCollisionShapeIndices=[col], linkVisualShapeIndices=[vis],
                                linkPositions=[[0, 0, 0]], linkOrientations=[[0, 0, 0, 1]],
                                linkInertialFramePositions=[[0, 0, 0]], linkInertialFrameOrientations=[[0, 0, 0, 1]],
                                linkParentIndices=[0], linkJointTypes=[p.JOINT_REVOLUTE], linkJointAxis=[[0, 0, 1]],
                                physicsClientId=cid)
        p.resetJointState(uid, 0, d.sign * math.radians(d.angle), physicsClientId=cid)
        return uid

    def _lamp_bodies(self, lamp) -> tuple[int, int]:
        cid = self.cid
        pole_h = lamp.z - 0.15
        col = p.createCollisionShape(p.GEOM_CYLINDER, radius=0.2, height=pole_h, physicsClientId=cid)
        vis = p.createVisualShapeArray(
            shapeTypes=[p.GEOM_CYLINDER, p.GEOM_CYLINDER], radii=[0.015, 0.16], lengths=[pole_h, 0.03],
            visualFramePositions=[[0, 0, 0], [0, 0, -pole_h / 2 + 0.015]],
            rgbaColors=[[0.15, 0.15, 0.15, 1], [0.15, 0.15, 0.15, 1]], physicsClientId=cid)
        pole = p.createMultiBody(0, col, vis, [lamp.x, lamp.y, pole_h / 2], physicsClientId=cid)
        shade_vis = p.createVisualShape(p.GEOM_CYLINDER, radius=0.2, length=0.3, rgbaColor=[*LAMP_OFF_COLOR, 1],
                                        physicsClientId=cid)
        shade = p.createMultiBody(0, -1, shade_vis, [lamp.x, lamp.y, lamp.z], physicsClientId=cid)
        return pole, shade

    def _landmark_body(self, m) -> None:
        cid = self.cid
        side = m.size / symbol_fraction(m.text)  # texture side incl. quiet zone
        nx, ny = math.cos(m.yaw), math.sin(m.yaw)
        # a 2 mm plate, the print 2.5 mm off the wall: the landmark map gives the wall point, and a
        # thicker panel biased every localization by its thickness along the code's normal
        back = p.createVisualShape(p.GEOM_BOX, halfExtents=[0.001, side / 2 + 0.02, side / 2 + 0.02],
                                   rgbaColor=[0.98, 0.98, 0.98, 1], physicsClientId=cid)
        p.createMultiBody(0, -1, back, [m.x + nx * 0.001, m.y + ny * 0.001, m.z], yaw_quat(m.yaw), physicsClientId=cid)
        h = side / 2
        # local frame: x = panel normal; a viewer facing the panel has +y on the right
        verts = [[0, -h, h], [0, h, h], [0, h, -h], [0, -h, -h]]  # TL, TR, BR, BL as seen
        uvs = [[0, 1], [1, 1], [1, 0], [0, 0]]
        quad = p.createVisualShape(p.GEOM_MESH, vertices=verts, indices=[0, 2, 1, 0, 3, 2], uvs=uvs,
                                   normals=[[1, 0, 0]] * 4, physicsClientId=cid)
        uid = p.createMultiBody(0, -1, quad, [m.x + nx * PRINT_OFFSET_M, m.y + ny * PRINT_OFFSET_M, m.z], yaw_quat(m.yaw),
                                physicsClientId=cid)
        tex = p.loadTexture(str(qr_texture(m.text, m.wear)), physicsClientId=cid)
        p.changeVisualShape(uid, -1, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=cid)

    def set_door_in_thread(self, door_id: str, angle_deg: float) -> None:
        """set_door from the world's pybullet thread (disturbances, the render process)."""
        d = next((d for d in self.plan.doors if d.id == door_id), None)
        if d is None:
            raise InvalidArgument(f"unknown door {door_id!r}")
        d.angle = float(angle_deg)
        p.resetJointState(self.door_uids[door_id], 0, d.sign * math.radians(d.angle), physicsClientId=self.cid)

    def _set_lamp(self, lamp_id: str, on: bool) -> None:
        lamp = next((lp for lp in self.plan.lamps if lp.id == lamp_id), None)
        if lamp is None:
            raise InvalidArgument(f"unknown lamp {lamp_id!r}")
        lamp.on = bool(on)
        shade = self.lamp_uids[lamp_id][1]
        color = LAMP_ON_COLOR if on else LAMP_OFF_COLOR
        p.changeVisualShape(shade, -1, rgbaColor=[*color, 1], physicsClientId=self.cid)
        if on:
            self.emissive[shade] = lamp_radiance(lamp.strength)
        else:
            self.emissive.pop(shade, None)
