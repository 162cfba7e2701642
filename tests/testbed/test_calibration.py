"""testbed.perception.homography on frames rendered through a KNOWN homography: recover it.

Each frame is a grey table with sensor noise and one ArUco marker (DICT_4X4_50) on a
white cap, warped into the picture by a chosen table-mm -> pixel homography with a real
perspective term, as the overhead camera sees the pusher's cap.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from drivers.yumi.arm_calibration import ArmCalibration
from testbed.perception import homography as cal
from testbed.perception.cube import WORKSPACE_POLYGON

W, H = 640, 480
# Table mm -> pixel: ~0.95 px/mm, u along -y, v along +x, a mild perspective (tilted camera).
TRUE = np.array([[0.0, -0.95, 320.0], [0.93, 0.02, -150.0], [2e-5, -3e-5, 1.0]])
CAP_MM = 44.0
MARKER_MM = 36.0  # the 6x6-cell code (with its black border) inside the white cap


def _marker_image(marker_id: int, cells_px: int = 20) -> np.ndarray:
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    code = cv2.aruco.generateImageMarker(d, marker_id, 6 * cells_px)
    pad = round(6 * cells_px * (CAP_MM - MARKER_MM) / MARKER_MM / 2)
    return cv2.copyMakeBorder(code, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)


def render(xy: list[tuple[float, float]] | tuple[float, float], ids: list[int] | int = 0,
           seed: int = 0, sigma: float = 2.0) -> np.ndarray:
    """BGR frame: markers centred at table points ``xy`` (mm), seen through TRUE."""
    rng = np.random.default_rng(seed)
    pts = [xy] if isinstance(xy, tuple) else xy
    mids = [ids] * len(pts) if isinstance(ids, int) else ids
    # Supersampled x4 then area-averaged, as a sensor integrates light over its pixels.
    ss = 4
    big = np.full((H * ss, W * ss), 120.0)
    for (x, y), mid in zip(pts, mids, strict=True):
        img = _marker_image(mid).astype(np.float64)
        s = img.shape[0]
        half = CAP_MM / 2
        src = np.float32([[0, 0], [s, 0], [s, s], [0, s]]) - 0.5  # outer pixel edges
        dst_mm = np.float64([[x - half, y + half], [x - half, y - half], [x + half, y - half],
                             [x + half, y + half]])
        # frame pixel p (centres at integers) is big pixel ss * (p + 0.5) - 0.5
        dst = (ss * (cal.apply_homography(TRUE, dst_mm) + 0.5) - 0.5).astype(np.float32)
        x0, y0 = np.floor(dst.min(0)).astype(int) - 2
        x1, y1 = np.ceil(dst.max(0)).astype(int) + 2  # warp only the cap's region: fast
        m = cv2.getPerspectiveTransform(src, dst - np.float32([x0, y0]))
        roi = big[y0:y1, x0:x1]
        warped = cv2.warpPerspective(img, m, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.ones_like(img), m, (x1 - x0, y1 - y0),
                                   flags=cv2.INTER_LINEAR)
        roi[:] = roi * (1 - mask) + warped
    frame = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA)
    frame += rng.normal(0, sigma, frame.shape)
    grey = np.clip(np.round(frame), 0, 255).astype(np.uint8)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)


def true_px(xy: tuple[float, float]) -> np.ndarray:
    return cal.apply_homography(TRUE, [xy])[0]


BOX = (300.0, -160.0, 620.0, 160.0)  # 320 mm square: images to ~300 px


def test_marker_centre_is_subpixel_accurate() -> None:
    errs = []
    for k, xy in enumerate([(350.0, -100.0), (460.0, 0.0), (590.0, 130.0), (470.3, 77.7)]):
        c = cal.find_marker(render(xy, seed=k), 0)
        assert c is not None
        errs.append(np.hypot(*(np.array(c) - true_px(xy))))
    assert max(errs) < 0.3, errs
    # another id is not this one
    assert cal.find_marker(render((460.0, 0.0), ids=1), 0) is None
    assert cal.find_marker(render((460.0, 0.0), ids=1), 1) is not None


def test_marker_centre_is_the_diagonals_crossing() -> None:
    sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    assert cal.marker_centre(sq) == pytest.approx((5.0, 5.0))
    warped = cal.apply_homography(TRUE, sq + 400)
    assert np.allclose(cal.marker_centre(warped), cal.apply_homography(TRUE, [(405, 405)])[0])


def test_fit_recovers_the_true_homography_and_rejects_an_outlier() -> None:
    pts = cal.grid_points(BOX, (5, 4))
    assert len(pts) == 20
    # one frame with all 20 markers would be ambiguous (same id): one frame per point
    pixels, table = [], []
    for k, xy in enumerate(pts):
        c = cal.find_marker(render(xy, seed=10 + k), 0)
        assert c is not None, xy
        pixels.append(c)
        table.append(xy)
    table[7] = (table[7][0] + 40.0, table[7][1])  # a TCP that did not reach its point
    fit = cal.fit_homography(pixels, table)
    assert fit.n_inliers == 19 and not fit.inliers[7]
    s = fit.summary()
    assert s["max_px"] < 0.5 and s["max_mm"] < 0.5, s
    # against the truth over the whole box, not just at the sightings
    xs, ys = np.meshgrid(np.linspace(BOX[0], BOX[2], 9), np.linspace(BOX[1], BOX[3], 9))
    mm = np.c_[xs.ravel(), ys.ravel()]
    px = cal.apply_homography(TRUE, mm)
    err_mm, = (np.linalg.norm(cal.apply_homography(fit.homography, px) - mm, axis=1),)
    err_px = np.linalg.norm(cal.apply_homography(np.linalg.inv(fit.homography), mm) - px, axis=1)
    assert err_px.max() < 0.5 and err_mm.max() < 0.5, (err_px.max(), err_mm.max())


def test_too_few_or_inconsistent_sightings_are_refused() -> None:
    pts = cal.grid_points(BOX, (2, 2)) + cal.grid_points(BOX, (3, 2))[1:2]
    px = cal.apply_homography(TRUE, pts)
    with pytest.raises(cal.CalibrationError, match="only 5 marker sightings"):
        cal.fit_homography(px, pts)
    rng = np.random.default_rng(0)
    junk = rng.uniform(0, 400, (12, 2))
    with pytest.raises(cal.CalibrationError):
        cal.fit_homography(junk, rng.uniform(0, 400, (12, 2)), ransac_mm=1.0)


def test_crop_proposal_is_a_square_around_the_workspace() -> None:
    h = np.linalg.inv(TRUE)
    x0, y0, x1, y1 = cal.propose_crop(h, BOX, (W, H))
    assert x1 - x0 == y1 - y0
    poly = cal.project_box(h, BOX)
    lo, hi = poly.min(0), poly.max(0)
    assert np.allclose([x0, y0, x1, y1], [*lo, *hi], atol=4)  # mild perspective
    assert x0 >= 0 and y0 >= 0 and x1 <= W and y1 <= H
    # a box hanging off the frame is shifted inside, never cut
    bx = cal.propose_crop(h, (BOX[0], BOX[1] + 200, BOX[2], BOX[3] + 200), (W, H))
    assert bx[0] == 0 and bx[2] - bx[0] == bx[3] - bx[1] > 0.95 * (x1 - x0)
    assert cal.in_view(h, (460.0, 0.0), (W, H))
    assert not cal.in_view(h, (100.0, 450.0), (W, H))


def test_parsers_and_grid() -> None:
    assert cal.parse_box("300,-160,620,160") == BOX
    assert cal.parse_grid("5x4") == (5, 4)
    for bad in ("1,2,3", "3,0,1,5", "a,b,c,d", "nan,0,1,1"):
        with pytest.raises(ValueError, match="--box"):
            cal.parse_box(bad)
    for bad in ("5", "1x4", "5x40", "axb"):
        with pytest.raises(ValueError, match="--grid"):
            cal.parse_grid(bad)
    pts = cal.grid_points(BOX, (3, 2), inset_mm=0)
    assert pts == [(300, -160), (460, -160), (620, -160), (620, 160), (460, 160), (300, 160)]


def test_calibration_data_keeps_the_other_keys_and_loads() -> None:
    pts = cal.grid_points(BOX, (4, 3))
    fit = cal.fit_homography(cal.apply_homography(TRUE, pts), pts)
    old = {"homography": np.eye(3).tolist(), "table_box_mm": [0, 0, 1, 1], "z_push_mm": 12.0,
           "rest_joints_deg": [40, -90, 30, 0, 40, 0, 135], "tool_z_mm": 184.2}
    data = cal.calibration_data(old, fit, BOX)
    assert data["z_push_mm"] == 12.0 and data["rest_joints_deg"] == old["rest_joints_deg"]
    assert data["table_box_mm"] == list(BOX)
    c = ArmCalibration.from_dict(data, "left")
    u, v = true_px((460.0, 10.0))
    assert c.pixel_to_table(u, v) == pytest.approx((460.0, 10.0), abs=1e-4)
    assert old["table_box_mm"] == [0, 0, 1, 1]  # not mutated


def test_overlays_draw_crop_workspace_and_box() -> None:
    frame = np.full((H, W, 3), 120, np.uint8)
    h = np.linalg.inv(TRUE)
    crop = cal.propose_crop(h, BOX, (W, H))
    arm = cal.ArmOverlay("left", crop, mirror=True, workspace_canonical=WORKSPACE_POLYGON,
                         table_box_px=cal.project_box(h, BOX),
                         markers_px=np.array([[320.0, 240.0]]))
    out = cal.draw_overlays(frame, [arm])
    assert out.shape == frame.shape and (frame == 120).all()  # the input is untouched
    x0, y0, x1, _ = crop
    assert (out[y0 + 20, x0] != 120).any() and (out[y0 + 20, x1 - 1] != 120).any()
    # the workspace's left edge at canonical x = 0.925 (mirrored) is drawn
    ws = cal.canonical_to_frame(crop, True, [(0.925, 0.5)])[0]
    assert (out[round(ws[1]), round(ws[0]) - 1 : round(ws[0]) + 2] != 120).any()
    assert (out[240, 320] != 120).any()
    assert cal.canonical_to_frame((10, 20, 110, 120), False, [(0.0, 1.0)])[0].tolist() == [10, 120]
