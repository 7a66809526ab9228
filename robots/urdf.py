"""Tiny URDF writer: robots are described in Python and written (content-hashed) into the cache dir."""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

from .qr import cache_dir


def box(sx: float, sy: float, sz: float) -> str:
    return f'<box size="{sx} {sy} {sz}"/>'


def cylinder(r: float, length: float) -> str:
    return f'<cylinder radius="{r}" length="{length}"/>'


def sphere(r: float) -> str:
    return f'<sphere radius="{r}"/>'


def _v(v) -> str:
    return " ".join(f"{x:.6g}" for x in v)


@dataclass
class JointDef:
    name: str
    kind: str  # revolute | prismatic | fixed
    parent: str
    child: str
    xyz: tuple = (0, 0, 0)
    rpy: tuple = (0, 0, 0)
    axis: tuple = (0, 0, 1)
    lower: float = 0.0
    upper: float = 0.0
    velocity: float = 2.0


@dataclass
class UrdfBuilder:
    name: str
    links: list[str] = field(default_factory=list)
    joints: list[JointDef] = field(default_factory=list)

    def link(self, name: str, *visuals: tuple) -> str:
        """visuals: (geometry_xml, xyz, rpy, rgba)"""
        parts = [f'<link name="{name}">',
                 '<inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>']
        for i, (geom, xyz, rpy, rgba) in enumerate(visuals):
            parts.append(f'<visual><origin xyz="{_v(xyz)}" rpy="{_v(rpy)}"/><geometry>{geom}</geometry>'
                         f'<material name="{name}_{i}"><color rgba="{_v(rgba)}"/></material></visual>')
        parts.append("</link>")
        self.links.append("".join(parts))
        return name

    def joint(self, j: JointDef) -> JointDef:
        self.joints.append(j)
        return j

    def xml(self) -> str:
        out = [f'<?xml version="1.0"?>\n<robot name="{self.name}">']
        out += self.links
        for j in self.joints:
            s = (f'<joint name="{j.name}" type="{j.kind}"><parent link="{j.parent}"/><child link="{j.child}"/>'
                 f'<origin xyz="{_v(j.xyz)}" rpy="{_v(j.rpy)}"/>')
            if j.kind != "fixed":
                s += (f'<axis xyz="{_v(j.axis)}"/><limit lower="{j.lower}" upper="{j.upper}" effort="10" '
                      f'velocity="{j.velocity}"/>')
            out.append(s + "</joint>")
        out.append("</robot>")
        return "\n".join(out)

    def write(self) -> Path:
        text = self.xml()
        path = cache_dir() / f"{self.name}_{hashlib.sha1(text.encode()).hexdigest()[:12]}.urdf"
        if not path.exists():
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)
        return path

    def limits(self) -> dict[str, tuple[float, float]]:
        return {j.name: (j.lower, j.upper) for j in self.joints if j.kind == "revolute"}
