"""Geometry of the YuMi hardware twin: the cell's layout and its camera model, in mm.

Why a module of its own: the layout (workspaces, rest pose, pusher, marker) and the
camera model (K, lens distortion, pose) are the contract that the server publishes at
``/lab/camera`` and that calibration, perception and the renderer must agree on to the
sub-pixel. Keeping them as plain numbers and numpy/cv2 functions (no PyBullet) makes
that contract easy to test and to read.

Frames: the robot's world frame (wobj0; the twin's base frame is its world frame),
millimetres, x forward (away from the robot), y to the
robot's left, z up, the table top at z = 0. The camera looks straight down from
``CAMERA_HEIGHT_MM`` above the workspaces' centre; its image axes are

    u (columns, right)  = world -y   (the left arm, y > 0, is on the left of the picture)
    v (rows, down)      = world -x   (the robot is at the bottom of the picture)

which is the only right-handed choice for a camera looking down with u along -y.
Pixel coordinates follow OpenCV: the centre of pixel (i, j) is at (i, j).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

# --- layout (mm) ------------------------------------------------------------------------
WORKSPACE_MM: Final = 320.0
"""Side of one arm's square workspace (the plain twin's WORKSPACE_M)."""
GAP_MM: Final = 100.0
"""Table between the two workspaces (they sit either side of y = 0): wide enough that
the two grippers over the inner edges stay 30 mm apart (issue 29, the arms' capsules in
``drivers/yumi/arm_shapes.py``)."""
WORKSPACE_X_MM: Final = 310.0
"""x of the workspaces' centres (in front of the robot): every corner reachable with a
100 mm pusher pointing down at an arm angle of +-135 deg, the nearest 42 mm inside the
reach (docs/notes/yumi-real.md, "Reach and kinematics"). At 400 mm the far outer corners
were out of an IRB 14000's reach."""
CUBE_MM: Final = 40.0
TABLE_BOX_MM: Final = (0.0, -480.0, 680.0, 480.0)
"""(x0, y0, x1, y1) of the finite table top; it covers the camera's whole view, and a
cube pushed past its edge falls to the floor."""
TABLE_THICKNESS_MM: Final = 40.0
FLOOR_Z_MM: Final = -750.0

PUSHER_RADIUS_MM: Final = 12.0
PUSHER_HEIGHT_MM: Final = 30.0
"""The pusher cylinder's bottom centre is the TCP; the cap's top face (the marker plane)
is PUSHER_HEIGHT_MM above it."""
CAP_MM: Final = 44.0
"""Side of the square cap on the pusher's top (white, carrying the marker)."""
MARKER_MM: Final = 36.0
"""Side of the ArUco marker's black square, centred on the cap (a 4 mm white margin)."""
MARKER_DICT: Final = "DICT_4X4_50"
MARKER_IDS: Final = {"left": 0, "right": 1}
REST_JOINTS_DEG: Final = {"left": (40.0, -90.0, 30.0, 0.0, 40.0, 0.0, 135.0),
                          "right": (-40.0, -90.0, 30.0, 0.0, 40.0, 0.0, -135.0)}
"""Each arm's rest pose, ABB's joint order (axes 1-6, then axis 7): ABB's folded arm and
wrist with axis 1 swung back and axis 2 raised. ABB's folded home of the IRB 14000 is
``[0, -130, 30, 0, 40, 0]`` with the arm angle +135 (left) / -135 (right) (public YuMi
RAPID: ``[[0,-130,30,0,40,0],[135,...]]``; an earlier rest held the arm out sideways, the
tip 0.7 m to the side, a bystander hazard, because it had that sign wrong). Exactly that
home cannot be the rest with the project's 184.2 mm pusher: its tip hangs at about
(149, +-141, 115) mm, over the workspaces' near edge and inside the overhead camera's
view (the driver's retake rule, which projects the TCP through the table homography with
a 2 % margin, would retake for ever). So axes 3-7 stay ABB's (30, 0, 40, 0, +-135: the
forearm and wrist folded, the pusher pointing down), axis 1 swings back 40 deg (away from
the table: +40 left, -40 right) and axis 2 rises to -90.

With the twin's model (``sim_twin.yumi_arms``) and the 184.2 mm pusher: the tip at
(-117, +-276, 268) mm, the flange at (-155, +-253, 447), behind the robot's front and
77 px outside the frame's 2 % margin in the table-plane projection (v 566 > 490; the tip
itself projects off the 480 px frame at v 650); every link 348 mm over the table (the
operator's model: 331), the arms' capsules 35 mm apart (at the shoulders, as in ABB's
home), every joint 33.5 deg from its limit; the joint path from rest to (310, +-210, 100)
with the pusher down stays above tb_zone_z + 20 outside the zone box
(tests/sim_twin/test_yumi_arms.py states the twin's figures; ``drivers/yumi/layout_check.py``
checks the operator's)."""
REST_MM: Final = {"left": (100.0, 450.0, 150.0), "right": (100.0, -450.0, 150.0)}
"""Each TCP's rest point in the plain cell (no arms): behind and beside the table, far
outside the camera's view. A cell with arms (the RWS twin) rests its pushers where the
rest joints hold them instead (``YumiTwinCell.set_rest``, ``sim_twin.yumi_arms.rest_tip``)."""

# --- camera -------------------------------------------------------------------------------
WIDTH: Final = 640
HEIGHT: Final = 480
CAMERA_HEIGHT_MM: Final = 1300.0
FOCAL_PX: Final = 1000.0
"""A 320 mm workspace at the cube-top plane (z = 40 mm) images to 254 px; both
workspaces and the gap (740 mm) fit the 640 px width with ~26 px to spare."""
PRINCIPAL_PX: Final = (319.5, 239.5)
DIST: Final = (-0.03, 0.0, 0.0, 0.0, 0.0)
"""OpenCV (k1, k2, p1, p2, k3): mild barrel distortion (1 px at the workspace corners)."""
NOISE_SIGMA: Final = 2.0
"""Gaussian sensor noise, grey levels."""
CROP_PLANE_Z_MM: Final = CUBE_MM
"""The crop boxes are the projection of each workspace at the cube-top plane (the plane
the calibration homography is fitted in)."""


def arm_side(arms: Sequence[str]) -> dict[str, str]:
    """Which side ("left" at y > 0, "right" at y < 0) each named arm works on: the names
    ``left``/``right`` say it; otherwise the first arm is the left one."""
    if not 1 <= len(arms) <= 2 or len(set(arms)) != len(arms):
        raise ValueError(f"a YuMi cell has one or two distinct arms, got {list(arms)}")
    sides: dict[str, str] = {}
    for i, name in enumerate(arms):
        sides[name] = name if name in ("left", "right") else ("left", "right")[i]
    if len(set(sides.values())) != len(sides):
        raise ValueError(f"arms {list(arms)} would share one side of the cell")
    return sides


def workspace_mm(side: str) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) of a side's workspace square on the table."""
    h = WORKSPACE_MM / 2
    yc = (GAP_MM / 2 + h) * (1.0 if side == "left" else -1.0)
    return (WORKSPACE_X_MM - h, yc - h, WORKSPACE_X_MM + h, yc + h)


@dataclass(frozen=True, slots=True)
class CameraModel:
    """The true camera: intrinsics ``K``, OpenCV distortion ``dist``, and the pose
    ``R``, ``t`` mapping world mm to camera mm (p_cam = R p_world + t)."""

    K: npt.NDArray[np.float64]
    dist: npt.NDArray[np.float64]
    R: npt.NDArray[np.float64]
    t: npt.NDArray[np.float64]
    width: int = WIDTH
    height: int = HEIGHT

    @classmethod
    def default(cls) -> CameraModel:
        K = np.array([[FOCAL_PX, 0.0, PRINCIPAL_PX[0]], [0.0, FOCAL_PX, PRINCIPAL_PX[1]],
                      [0.0, 0.0, 1.0]])
        R = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
        centre = np.array([WORKSPACE_X_MM, 0.0, CAMERA_HEIGHT_MM])
        return cls(K, np.array(DIST, dtype=np.float64), R, -R @ centre)

    @property
    def rvec(self) -> npt.NDArray[np.float64]:
        r, _ = cv2.Rodrigues(self.R)
        return r.ravel()

    def project(self, xyz_mm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Pixels (N, 2) of world points (N, 3) or (3,), through the lens distortion."""
        p = np.asarray(xyz_mm, dtype=np.float64).reshape(-1, 3)
        uv, _ = cv2.projectPoints(p, self.rvec, self.t, self.K, self.dist)
        return uv.reshape(-1, 2)

    def project_ideal(self, xyz_mm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Pixels (N, 2) of the same points through the distortion-free pinhole."""
        p = np.asarray(xyz_mm, dtype=np.float64).reshape(-1, 3)
        c = p @ self.R.T + self.t
        uv = c[:, :2] / c[:, 2:3]
        return uv @ self.K[:2, :2].T + self.K[:2, 2]

    def undistort_pixels(self, uv: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Ideal (pinhole) pixels of distorted pixels (N, 2)."""
        d = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        k1, k2, p1, p2, k3 = self.dist
        xd, yd = (d[:, 0] - cx) / fx, (d[:, 1] - cy) / fy
        x, y = xd.copy(), yd.copy()
        for _ in range(20):  # fixed point of the forward model (converges fast: mild lens)
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            x, y = (xd - dx) / radial, (yd - dy) / radial
        return np.stack([x * fx + cx, y * fy + cy], axis=1)

    def distortion_maps(self, margin: int) -> tuple[npt.NDArray[np.float32],
                                                    npt.NDArray[np.float32]]:
        """cv2.remap maps: for every pixel of the distorted picture, where to sample an
        ideal picture rendered with ``margin`` extra pixels on every side."""
        vs, us = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        ideal = self.undistort_pixels(np.stack([us.ravel(), vs.ravel()], axis=1)) + margin
        return (ideal[:, 0].reshape(self.height, self.width).astype(np.float32),
                ideal[:, 1].reshape(self.height, self.width).astype(np.float32))

    def image_yaw(self, world_yaw: float) -> float:
        """The angle, in image axes (u right, v down), of the world direction at
        ``world_yaw`` about z, reduced modulo a quarter turn to [-pi/4, pi/4) (a cube's
        yaw as ``testbed.perception.cube`` reports it)."""
        d = self.R[:2, :2] @ np.array([math.cos(world_yaw), math.sin(world_yaw)])
        q = math.pi / 2
        return (math.atan2(d[1], d[0]) + q / 2) % q - q / 2

    def crop_box(self, box_mm: Sequence[float], z_mm: float = CROP_PLANE_Z_MM
                 ) -> tuple[int, int, int, int]:
        """The square pixel box (x0, y0, x1, y1) of a table box's projection at height
        ``z_mm``: centred on the projected corners' mean, its side their mean extent."""
        x0, y0, x1, y1 = box_mm
        corners = [(x0, y0, z_mm), (x1, y0, z_mm), (x1, y1, z_mm), (x0, y1, z_mm)]
        uv = self.project(corners)
        side = round(float(np.mean(uv.max(0) - uv.min(0))))
        cu, cv = uv.mean(0)
        u0, v0 = round(cu - side / 2), round(cv - side / 2)
        return (u0, v0, u0 + side, v0 + side)

    def as_json(self) -> dict[str, object]:
        return {"width": self.width, "height": self.height, "K": self.K.tolist(),
                "dist": self.dist.tolist(), "R": self.R.tolist(), "t": self.t.tolist(),
                "rvec": self.rvec.tolist(), "tvec": self.t.tolist()}
