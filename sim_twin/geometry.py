"""Plane geometry of the canonical frame: the workspace polygon and the face directions.

Why separate: the cell (task semantics), the supervisor (planning) and the tests all ask
the same two questions -- how deep inside the workspace is a point, and which way does
face ``k`` push a cube of yaw ``psi`` -- and must get the same answer.

Canonical yaw: the angle of a cube edge in the canonical frame (x right, y down), as
``atan2(dy, dx)``, reduced modulo a quarter turn into ``[-pi/4, pi/4)`` (a cube looks
the same after a quarter turn).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from sim_twin.constants import FACE_DIRECTIONS, WORKSPACE_POLYGON

FloatArray = npt.NDArray[np.float64]


def reduce_yaw(yaw: float) -> float:
    """Yaw modulo a quarter turn, in ``[-pi/4, pi/4)``."""
    q = math.pi / 2
    return (yaw + q / 2) % q - q / 2


def push_direction(face: int, yaw: float) -> FloatArray:
    """Canonical unit vector along which pushing face ``face`` moves a cube of ``yaw``.

    Object-centric: ``FACE_DIRECTIONS[face]`` turned by the cube's reduced yaw, i.e. the
    inward normal of the face that is closest to facing that direction.
    """
    psi = reduce_yaw(yaw)
    c, s = math.cos(psi), math.sin(psi)
    dx, dy = FACE_DIRECTIONS[face]
    return np.array([c * dx - s * dy, s * dx + c * dy])


def _edge_frame(polygon: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Vertices and inward unit normals of a convex polygon's edges (either winding)."""
    v = np.asarray(polygon, dtype=np.float64)
    e = np.roll(v, -1, axis=0) - v
    n = np.stack([-e[:, 1], e[:, 0]], axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    x, y = v[:, 0], v[:, 1]
    signed_area = 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    if signed_area < 0:
        n = -n
    return v, n


_VERTS, _NORMALS = _edge_frame(WORKSPACE_POLYGON)


def depth_inside(points: npt.ArrayLike, polygon: FloatArray | None = None) -> FloatArray:
    """Signed depth of points inside a convex polygon: the smallest distance to an edge's
    line, positive inside, negative outside (for points outside it is the largest
    violated edge distance, negated -- exact for the inside test and a margin test).

    ``points``: (2,) or (N, 2); returns () or (N,).
    """
    verts, normals = (_VERTS, _NORMALS) if polygon is None else _edge_frame(polygon)
    p = np.asarray(points, dtype=np.float64)
    d = np.einsum("...j,ij->...i", p, normals) - np.sum(verts * normals, axis=1)
    return np.min(d, axis=-1)
