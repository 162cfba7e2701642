"""Window geometry: canonical <-> window pixels and where face marker k sits."""

from __future__ import annotations

import pytest

from gui.layout import ConsoleLayout, CubeMarker


def test_sizes_and_mapping() -> None:
    lay = ConsoleLayout(scale=6)
    assert lay.image_px == 384 >= 256
    assert (lay.width, lay.height) == (384, lay.header_h + 384 + lay.footer_h)
    assert lay.to_window((0.0, 0.0)) == (0, lay.header_h)
    assert lay.to_window((0.5, 0.25)) == (192, lay.header_h + 96)
    assert lay.to_canonical(lay.to_window((0.3, 0.6))) == pytest.approx((0.3, 0.6), abs=1e-2)
    assert lay.in_image((10, lay.header_h)) and not lay.in_image((10, lay.header_h - 1))


def test_too_small_is_refused() -> None:
    with pytest.raises(ValueError, match="256"):
        ConsoleLayout(scale=3)


def test_face_points_follow_face_directions() -> None:
    lay = ConsoleLayout(scale=6)
    cube = CubeMarker((0.5, 0.5))
    cx, cy = lay.to_window(cube.centre)
    up, left, down, right = lay.face_points(cube)
    assert up[0] == cx and up[1] < cy
    assert left[1] == cy and left[0] < cx
    assert down[0] == cx and down[1] > cy
    assert right[1] == cy and right[0] > cx
    assert lay.face_points(None) == lay.face_points(CubeMarker((0.5, 0.5), found=False))


def test_face_points_stay_inside_the_image() -> None:
    lay = ConsoleLayout(scale=4)
    for point in lay.face_points(CubeMarker((0.1, 0.9))):
        assert lay.in_image(point)
