"""Image-to-table calibration of one arm from an ArUco marker on its pusher.

Why it looks like this: the YuMi backend turns a camera pixel into a table point with a
3x3 homography (``drivers.yumi.arm_calibration.ArmCalibration``), which is exact for ONE plane
under a pinhole camera. The plane that matters is the cube's top face (40 mm above the
table), where perception sees the cube's centre; a marker on the pusher's cap, 30 mm
above the TCP, sits in that plane when the TCP is at z = 10 mm. So ``testbed
calibrate`` drives the TCP over a grid, finds the marker's centre in each full frame,
and fits pixel -> TCP (x, y) in mm. Everything here is a pure function of frames and
numbers (no robot, no I/O), so it is tested on frames rendered through a known
homography; ``testbed.lab.calibrate`` does the driving.

    grid of TCP points (mm) --move_tcp--> frame --ArUco + cornerSubPix--> marker centre (px)
    (px, mm) pairs --RANSAC findHomography--> H: pixel -> mm, reprojection errors px / mm
    H^-1(table box or workspace) --> proposed square crop box
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
Frame = npt.NDArray[np.uint8]
Box = tuple[float, float, float, float]
PixelBox = tuple[int, int, int, int]

MARKER_DICT = "DICT_4X4_50"
"""The pusher caps' ArUco dictionary (small codes: robust at ~25 px per side)."""
DEFAULT_MARKER_IDS: Mapping[str, int] = {"left": 0, "right": 1}
MIN_MARKERS = 8
"""Fewer sightings than this and the fit is refused (8 unknowns, need redundancy)."""
CALIBRATION_KEYS = frozenset({"homography", "table_box_mm"})
"""The keys a calibration writes; every other key of an existing file is kept."""


# -- detection -----------------------------------------------------------------------
def _detector(dict_name: str = MARKER_DICT) -> cv2.aruco.ArucoDetector:
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dict_name))
    params = cv2.aruco.DetectorParameters()
    # We refine the corners ourselves (cornerSubPix on the grey frame, window sized to
    # the marker), so the detector's own refinement is off.
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    return cv2.aruco.ArucoDetector(dictionary, params)


def detect_markers(frame: Frame, dict_name: str = MARKER_DICT) -> dict[int, FloatArray]:
    """Every marker of ``dict_name`` in a BGR (or grey) frame: id -> (4, 2) corners, px.

    Corners are refined to sub-pixel accuracy with ``cv2.cornerSubPix``. Its window must
    stay inside the marker's black border cell (1/6 of the side) and off the cap's edge
    beyond the white margin, or their edges pull the corner: half-window ~side/16, at
    least 2 px (measured: 0.2 px centre error at 34 px per side, 0.5 px with 3 px).
    A marker id seen twice is dropped (ambiguous).
    """
    grey = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    corners, ids, _ = _detector(dict_name).detectMarkers(grey)
    if ids is None:
        return {}
    found: dict[int, FloatArray] = {}
    seen: set[int] = set()
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.001)
    for c, i in zip(corners, ids.ravel(), strict=True):
        mid = int(i)
        if mid in seen:
            found.pop(mid, None)
            continue
        seen.add(mid)
        pts = np.ascontiguousarray(c.reshape(4, 1, 2), dtype=np.float32)
        side = float(np.mean(np.linalg.norm(pts[:, 0] - np.roll(pts[:, 0], 1, axis=0),
                                             axis=1)))
        win = max(2, min(6, round(side / 16)))
        cv2.cornerSubPix(grey, pts, (win, win), (-1, -1), criteria)
        found[mid] = pts.reshape(4, 2).astype(np.float64)
    return found


def marker_centre(corners: npt.ArrayLike) -> tuple[float, float]:
    """The marker's centre in the image: the intersection of its diagonals.

    Under a perspective the centre of a square maps to the crossing of the images of its
    diagonals, not to the mean of its corners (off by up to ~0.1 px here, but free).
    """
    p = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    h = [np.append(q, 1.0) for q in p]
    x = np.cross(np.cross(h[0], h[2]), np.cross(h[1], h[3]))
    if abs(x[2]) < 1e-12:
        m = p.mean(axis=0)
        return (float(m[0]), float(m[1]))
    return (float(x[0] / x[2]), float(x[1] / x[2]))


def find_marker(frame: Frame, marker_id: int, dict_name: str = MARKER_DICT
                ) -> tuple[float, float] | None:
    """Centre (u, v) of marker ``marker_id`` in ``frame``, or None if it is not seen."""
    corners = detect_markers(frame, dict_name).get(marker_id)
    return None if corners is None else marker_centre(corners)


# -- fitting -------------------------------------------------------------------------
def apply_homography(h: npt.ArrayLike, pts: npt.ArrayLike) -> FloatArray:
    """Map (N, 2) points through a 3x3 homography."""
    p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    q = np.hstack([p, np.ones((len(p), 1))]) @ np.asarray(h, dtype=np.float64).T
    return q[:, :2] / q[:, 2:3]


@dataclass(frozen=True)
class HomographyFit:
    """A fitted pixel -> table homography and how well it explains the sightings."""

    homography: FloatArray
    """3x3, camera pixel (u, v, 1) -> table (x, y, w) in mm, normalised H[2, 2] = 1."""
    pixels: FloatArray
    table_mm: FloatArray
    inliers: npt.NDArray[np.bool_]
    error_px: FloatArray
    """Per inlier: |H^-1(table) - pixel|, in pixels."""
    error_mm: FloatArray
    """Per inlier: |H(pixel) - table|, in mm."""

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())

    @property
    def n_outliers(self) -> int:
        return int((~self.inliers).sum())

    def summary(self) -> dict[str, float]:
        return {"median_px": float(np.median(self.error_px)), "max_px": float(self.error_px.max()),
                "median_mm": float(np.median(self.error_mm)), "max_mm": float(self.error_mm.max())}


class CalibrationError(ValueError):
    """The sightings cannot give a calibration; ``str()`` says why in one line."""


def fit_homography(pixels: npt.ArrayLike, table_mm: npt.ArrayLike, *, ransac_mm: float = 4.0,
                   min_points: int = MIN_MARKERS) -> HomographyFit:
    """RANSAC fit of pixel -> table mm, then least squares on the inliers.

    ``ransac_mm`` is the inlier threshold in table millimetres (the destination space of
    ``cv2.findHomography``): a mis-detected marker or a TCP that did not reach its
    point is dropped. Raises CalibrationError with fewer than ``min_points`` sightings
    or inliers, or a degenerate fit.
    """
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    mm = np.asarray(table_mm, dtype=np.float64).reshape(-1, 2)
    if len(px) != len(mm):
        raise ValueError(f"{len(px)} pixels but {len(mm)} table points")
    if len(px) < min_points:
        raise CalibrationError(f"only {len(px)} marker sightings, need at least {min_points}")
    h, mask = cv2.findHomography(px, mm, cv2.RANSAC, ransac_mm, maxIters=5000,
                                 confidence=0.999)
    if h is None or mask is None:
        raise CalibrationError("no homography fits the sightings (points collinear?)")
    inl = mask.ravel().astype(bool)
    if int(inl.sum()) < min_points:
        raise CalibrationError(f"only {int(inl.sum())} of {len(px)} sightings agree with one "
                               f"homography (need {min_points}); check the marker id and TCP")
    # Least squares over every inlier (RANSAC's refit is on its last sample consensus).
    h, _ = cv2.findHomography(px[inl], mm[inl], 0)
    if h is None or abs(np.linalg.det(h)) < 1e-12 or not np.all(np.isfinite(h)):
        raise CalibrationError("the fitted homography is degenerate")
    h = h / h[2, 2]
    err_px, err_mm = reprojection_errors(h, px[inl], mm[inl])
    return HomographyFit(h, px, mm, inl, err_px, err_mm)


def reprojection_errors(h: npt.ArrayLike, pixels: npt.ArrayLike, table_mm: npt.ArrayLike
                        ) -> tuple[FloatArray, FloatArray]:
    """(pixel error, mm error) per point of a pixel -> mm homography ``h``."""
    h = np.asarray(h, dtype=np.float64)
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    mm = np.asarray(table_mm, dtype=np.float64).reshape(-1, 2)
    err_mm = np.linalg.norm(apply_homography(h, px) - mm, axis=1)
    err_px = np.linalg.norm(apply_homography(np.linalg.inv(h), mm) - px, axis=1)
    return err_px, err_mm


# -- grid, crop, rest ----------------------------------------------------------------
def parse_box(text: str, flag: str = "--box") -> Box:
    """``"x0,y0,x1,y1"`` (mm) -> a box with x0 < x1, y0 < y1; ValueError names ``flag``."""
    try:
        v = tuple(float(s) for s in text.split(","))
    except ValueError:
        raise ValueError(f"{flag}: {text!r} is not 4 numbers x0,y0,x1,y1 (mm)") from None
    if len(v) != 4 or not all(math.isfinite(x) for x in v):
        raise ValueError(f"{flag}: {text!r} is not 4 numbers x0,y0,x1,y1 (mm)")
    if v[0] >= v[2] or v[1] >= v[3]:
        raise ValueError(f"{flag}: {text!r} needs x0 < x1 and y0 < y1")
    return (v[0], v[1], v[2], v[3])


def parse_grid(text: str) -> tuple[int, int]:
    """``"5x4"`` -> (5, 4) points along x and y; each at least 2, at most 20."""
    parts = text.lower().split("x")
    try:
        nx, ny = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"--grid: {text!r} is not NXxNY (e.g. 5x4)") from None
    if not (2 <= nx <= 20 and 2 <= ny <= 20):
        raise ValueError(f"--grid: {text!r} needs 2..20 points along each axis")
    return (nx, ny)


def grid_points(box: Box, grid: tuple[int, int], inset_mm: float = 1.0
                ) -> list[tuple[float, float]]:
    """``nx * ny`` points covering ``box`` (inset by ``inset_mm``), boustrophedon order.

    The snake order keeps each move short (the arm travels at z_travel between points).
    """
    x0, y0, x1, y1 = box
    xs = np.linspace(x0 + inset_mm, x1 - inset_mm, grid[0])
    ys = np.linspace(y0 + inset_mm, y1 - inset_mm, grid[1])
    out: list[tuple[float, float]] = []
    for j, y in enumerate(ys):
        row = xs if j % 2 == 0 else xs[::-1]
        out += [(float(x), float(y)) for x in row]
    return out


def project_box(h: npt.ArrayLike, box: Box, samples: int = 8) -> FloatArray:
    """The outline of a table box (mm) in the image through a pixel -> mm ``h``.

    Sampled along each edge, so the polygon stays right if ``h`` is nearly affine.
    """
    x0, y0, x1, y1 = box
    t = np.linspace(0.0, 1.0, samples, endpoint=False)
    edges = [np.c_[x0 + (x1 - x0) * t, np.full_like(t, y0)],
             np.c_[np.full_like(t, x1), y0 + (y1 - y0) * t],
             np.c_[x1 - (x1 - x0) * t, np.full_like(t, y1)],
             np.c_[np.full_like(t, x0), y1 - (y1 - y0) * t]]
    return apply_homography(np.linalg.inv(np.asarray(h, dtype=np.float64)), np.vstack(edges))


def propose_crop(h: npt.ArrayLike, box: Box, frame_size: tuple[int, int]) -> PixelBox:
    """The square pixel box (x0, y0, x1, y1) of the projection of ``box`` (mm).

    Square because the crop is resized to 64x64: centred on the mean of the box's
    projected corners, its side their mean extent (as the hardware twin publishes its
    natural crops, so a good calibration proposes the same box); shifted (not shrunk)
    to stay inside the frame of ``frame_size`` = (width, height), shrunk only if it is
    larger than the frame.
    """
    w, hgt = frame_size
    x0, y0, x1, y1 = box
    uv = apply_homography(np.linalg.inv(np.asarray(h, dtype=np.float64)),
                          [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
    side = min(round(float(np.mean(uv.max(0) - uv.min(0)))), w, hgt)
    cx, cy = uv.mean(axis=0)
    u0 = min(max(round(cx - side / 2.0), 0), w - side)
    v0 = min(max(round(cy - side / 2.0), 0), hgt - side)
    return (int(u0), int(v0), int(u0 + side), int(v0 + side))


def in_view(h: npt.ArrayLike, xy_mm: Sequence[float], frame_size: tuple[int, int],
            margin_px: float = 30.0) -> bool:
    """Whether table point ``xy_mm`` maps into the frame (grown by ``margin_px``).

    A rough test for the rest pose (the homography is for the calibration plane, not the
    rest height), so the margin is generous: a pusher near the edge counts as in view.
    """
    (u, v), = apply_homography(np.linalg.inv(np.asarray(h, dtype=np.float64)), [xy_mm[:2]])
    w, hgt = frame_size
    return bool(-margin_px <= u <= w + margin_px and -margin_px <= v <= hgt + margin_px)


def calibration_data(existing: Mapping[str, Any] | None, fit: HomographyFit, table_box_mm: Box
                     ) -> dict[str, Any]:
    """The calibration file's content: ``existing`` with the homography and box replaced.

    Every other key (rest pose, speeds, heights) is kept as the lab set it; the result
    is what ``ArmCalibration.from_dict`` accepts.
    """
    data = dict(existing or {})
    data["homography"] = [[float(v) for v in row] for row in fit.homography]
    data["table_box_mm"] = [float(v) for v in table_box_mm]
    return data


# -- drawing -------------------------------------------------------------------------
@dataclass(frozen=True)
class ArmOverlay:
    """What to draw of one arm on the full camera frame."""

    name: str
    crop: PixelBox | None
    mirror: bool = False
    workspace_canonical: FloatArray | None = None
    """The arm's workspace polygon in canonical units (perception.WORKSPACE_POLYGON)."""
    table_box_px: FloatArray | None = None
    """The calibration's table box projected into the frame (from its homography)."""
    markers_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    """Marker sightings to mark (calibration): (N, 2) pixels."""


def canonical_to_frame(crop: PixelBox, mirror: bool, pts: npt.ArrayLike) -> FloatArray:
    """Canonical crop coordinates (0..1, mirrored arms flipped in x) -> frame pixels.

    The inverse of the backend's crop: cut (x0, y0, x1, y1), flip if mirrored, resize.
    """
    x0, y0, x1, y1 = crop
    p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    cx = 1.0 - p[:, 0] if mirror else p[:, 0]
    return np.c_[x0 + cx * (x1 - x0), y0 + p[:, 1] * (y1 - y0)]


_COLOURS = [(255, 200, 0), (0, 200, 255), (255, 0, 200), (0, 255, 120)]


def draw_overlays(frame: Frame, arms: Sequence[ArmOverlay]) -> Frame:
    """A copy of a BGR frame with each arm's crop box, workspace and table box drawn.

    Crop box: a rectangle labelled with the arm's name (an arrow marks a mirrored crop's
    canonical x axis); workspace: the canonical polygon through crop/mirror; table box:
    a thin dashed-looking polyline through the calibration; sightings: small crosses.
    """
    out = frame.copy() if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    for k, arm in enumerate(arms):
        colour = _COLOURS[k % len(_COLOURS)]
        if arm.table_box_px is not None:
            poly = np.round(arm.table_box_px).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(out, [poly], True, (200, 200, 200), 1, cv2.LINE_AA)
        if arm.crop is not None:
            x0, y0, x1, y1 = arm.crop
            cv2.rectangle(out, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
            label = f"{arm.name}{' (mirrored)' if arm.mirror else ''}"
            cv2.putText(out, label, (x0 + 4, max(y0 - 6, 12)), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                        colour, 1, cv2.LINE_AA)
            a, b = canonical_to_frame(arm.crop, arm.mirror, [(0.05, 0.03), (0.2, 0.03)])
            cv2.arrowedLine(out, (round(a[0]), round(a[1])), (round(b[0]), round(b[1])),
                            colour, 1, cv2.LINE_AA, tipLength=0.3)
            if arm.workspace_canonical is not None:
                ws = canonical_to_frame(arm.crop, arm.mirror, arm.workspace_canonical)
                cv2.polylines(out, [np.round(ws).astype(np.int32).reshape(-1, 1, 2)], True,
                              colour, 1, cv2.LINE_AA)
        for u, v in np.asarray(arm.markers_px, dtype=np.float64).reshape(-1, 2):
            cv2.drawMarker(out, (round(u), round(v)), colour, cv2.MARKER_CROSS, 8, 1)
    return out
