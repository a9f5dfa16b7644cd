"""Small URDFs written by the tests: massless links joined by revolute, prismatic and fixed joints."""

from __future__ import annotations

L1, L2 = 0.7, 0.4


def urdf(name: str, joints: list[tuple[str, str, str, str, str, str]]) -> str:
    """A URDF of massless links joined by ``(type, parent, child, xyz, rpy, axis)`` joints."""
    links = sorted({link for _, parent, child, *_ in joints for link in (parent, child)})
    body = [f'<link name="{link}"/>' for link in links]
    for i, (kind, parent, child, xyz, rpy, axis) in enumerate(joints):
        limit = '<limit lower="-3" upper="3" effort="1" velocity="1"/>' if kind != "fixed" else ""
        axis_tag = f'<axis xyz="{axis}"/>' if axis else ""
        body.append(
            f'<joint name="j{i}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/>{axis_tag}{limit}</joint>'
        )
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n' + "\n".join(body) + "\n</robot>\n"


PLANAR_URDF = urdf("planar2", [
    ("revolute", "base", "link1", "0 0 0", "0 0 0", "0 0 1"),
    ("revolute", "link1", "link2", f"{L1} 0 0", "0 0 0", "0 0 1"),
    ("fixed", "link2", "tip", f"{L2} 0 0", "0 0 0", ""),
])

SPATIAL_URDF = urdf("spatial3", [
    ("revolute", "base", "a", "0.1 0 0.3", "0.2 -0.4 0.7", "0.3 -0.5 0.8"),  # unaligned axis
    ("prismatic", "a", "b", "0 0.2 0", "1.0 0 0.3", "0 1 0"),
    ("revolute", "b", "c", "0.4 0 0.1", "0 0.5 0", "1 0 0"),
    ("fixed", "c", "ee", "0.05 0.1 -0.2", "0.3 0.2 0.1", ""),
])
