"""The calibration marker: the printable caps and the mounting drawing (robot/README.md).

    .venv/bin/python scripts/calibration_marker.py            # all three, into docs/
    .venv/bin/python scripts/calibration_marker.py --out-dir DIR [--ids 0,1] [--no-drawing]

It writes, for each id (0: the left arm, 1: the right), ``calibration-marker-<id>.png``: the
cap to print, a white square 44 mm a side with its cutting line, the ArUco marker
(OpenCV's ``DICT_4X4_50``) 36 mm a side centred on it, and what to check under it; at
24 pixels per mm (609.6 DPI, stored in the PNG, so a print at 100 % is to scale). And
``calibration-marker.png``: the mounting drawing, both caps from above as the camera sees
them and the pusher from the side, with the dimensions ``testbed calibrate`` assumes.

Why a script without ``testbed``: a lab prints the marker on day one, possibly on another
machine, with nothing but OpenCV and numpy (and matplotlib, Pillow for the drawing and the
PNG's resolution); the figures are the project's (``sim_twin/yumi_geometry.py``,
``testbed/lab/calibrate.py``), kept equal by ``tests/test_calibration_marker.py``, which
also detects every printed marker with OpenCV and its id.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from matplotlib.axes import Axes

DOCS = Path(__file__).resolve().parents[1] / "docs"
MARKER_DICT = "DICT_4X4_50"
MARKER_IDS = {"left": 0, "right": 1}
MARKER_MM = 36.0
"""The black square's side (the marker with its one-cell black border)."""
CAP_MM = 44.0
"""The white cap's side: a 4 mm white margin around the marker, which the detector needs."""
ABOVE_TIP_MM = 30.0
"""The marker's plane above the pusher's tip (``testbed calibrate --marker-above-tcp``)."""
PUSH_Z_MM = 10.0
"""The tip's height at every grid point (``--z``): the marker then lies at z 40 mm, the
top face of a 40 mm cube, where perception measures the cubes."""
ROD_MM = (100.0, 10.0, 30.0)
"""The pusher rod: length, diameter, how far it sits in the gripper's fingers (robot/README.md,
"The tool load")."""
PX_PER_MM = 24
"""Print resolution: 24 px/mm (609.6 DPI) puts each of the marker's 6 cells on exactly
144 px, so the printed square is 36 mm with no resampling."""


def marker_sheet(marker_id: int, px_per_mm: int = PX_PER_MM) -> npt.NDArray[np.uint8]:
    """The printable cap of ``marker_id`` (grey, ``px_per_mm``): 64 x 68 mm, the 44 mm cap
    with a dashed cutting line just outside it, the 36 mm marker centred on the cap, and
    three lines of text under it (outside the cap: nothing near the marker but white)."""
    k = px_per_mm
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICT))
    side = round(MARKER_MM * k)
    marker = cv2.aruco.generateImageMarker(dictionary, marker_id, side)
    width, height = 64 * k, 68 * k
    sheet = np.full((height, width), 255, np.uint8)
    cap = round(CAP_MM * k)
    x0, y0 = (width - cap) // 2, 4 * k
    m0 = (cap - side) // 2
    sheet[y0 + m0:y0 + m0 + side, x0 + m0:x0 + m0 + side] = marker
    _dashed_square(sheet, x0 - k // 4, y0 - k // 4, cap + k // 2, 150, dash=2 * k)
    arm = next((a for a, i in MARKER_IDS.items() if i == marker_id), None)
    text = [f"{MARKER_DICT} id {marker_id}" + (f": the {arm} arm" if arm else ""),
            f"black square {MARKER_MM:g} mm: print at 100 %, measure it",
            f"cut on the dashes: cap {CAP_MM:g} mm; plane {ABOVE_TIP_MM:g} mm above the tip"]
    for n, line in enumerate(text):
        cv2.putText(sheet, line, (2 * k, y0 + cap + (6 + 5 * n) * k), cv2.FONT_HERSHEY_SIMPLEX,
                    0.055 * k, 0, max(1, k // 8), cv2.LINE_AA)
    return sheet


def _dashed_square(img: npt.NDArray[np.uint8], x: int, y: int, size: int, grey: int,
                   dash: int) -> None:
    """A thin dashed outline (the cutting line) of a square, in place."""
    t = max(1, dash // 16)
    for a in range(0, size, 2 * dash):
        b = min(a + dash, size)
        img[y:y + t, x + a:x + b] = grey
        img[y + size - t:y + size, x + a:x + b] = grey
        img[y + a:y + b, x:x + t] = grey
        img[y + a:y + b, x + size - t:x + size] = grey


def save_sheet(path: Path, sheet: npt.NDArray[np.uint8], px_per_mm: int = PX_PER_MM) -> None:
    """Write the sheet as a grey PNG whose stored resolution makes a 100 % print to scale."""
    from PIL import Image

    dpi = px_per_mm * 25.4
    Image.fromarray(sheet).save(path, dpi=(dpi, dpi), optimize=True)


def _top_view(ax: Axes, marker_id: int, arm: str) -> None:
    """One cap from above, as the overhead camera sees it, with its dimensions."""
    from matplotlib.patches import Circle, Rectangle

    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, MARKER_DICT))
    img = cv2.aruco.generateImageMarker(dictionary, marker_id, 120)
    h, m = CAP_MM / 2, MARKER_MM / 2
    ax.add_patch(Rectangle((-h, -h), CAP_MM, CAP_MM, fc="white", ec="0.3", lw=1.2))
    ax.imshow(img, cmap="gray", extent=(-m, m, -m, m), zorder=2)
    ax.add_patch(Circle((0, 0), ROD_MM[1] / 2, fill=False, ec="tab:red", ls="--", lw=1.2,
                        zorder=3, label="rod (below)"))
    for y, half, what in ((-h - 5, h, f"cap {CAP_MM:g}"), (h + 5, m, f"marker {MARKER_MM:g}")):
        ax.annotate("", (-half, y), (half, y), arrowprops={"arrowstyle": "<->", "lw": 0.8})
        ax.text(0, y + (2 if y > 0 else -2), f"{what} mm", ha="center",
                va="bottom" if y > 0 else "top", fontsize=8)
    ax.text(h + 1, -h, f"{(CAP_MM - MARKER_MM) / 2:g} mm white\nmargin", fontsize=7,
            va="bottom")
    ax.set(xlim=(-34, 40), ylim=(-36, 36), aspect="equal", xticks=[], yticks=[],
           title=f"{arm} arm: {MARKER_DICT} id {marker_id}\nfrom above, centred on the rod")


def _side_view(ax: Axes) -> None:
    """The pusher from the side at a grid point: tip, cap, marker plane, fingers, table."""
    from matplotlib.patches import Rectangle

    length, dia, held = ROD_MM
    tip, plane = PUSH_Z_MM, PUSH_Z_MM + ABOVE_TIP_MM
    top = tip + length
    ax.add_patch(Rectangle((-90, -6), 240, 6, fc="0.85", ec="0.5"))
    ax.add_patch(Rectangle((-85, 0), 40, 40, fill=False, ec="0.4", ls=":"))
    ax.text(-65, 20, "40 mm\ncube", ha="center", va="center", fontsize=7, color="0.4")
    ax.add_patch(Rectangle((-dia / 2, tip), dia, length, fc="tab:red", alpha=0.6))
    for x in (-dia / 2 - 8, dia / 2):  # the fingers, 8 mm thick, holding the rod's top
        ax.add_patch(Rectangle((x, top - held), 8, held + 12, fc="0.6", ec="0.3"))
    ax.add_patch(Rectangle((-CAP_MM / 2, plane - 3), CAP_MM, 3, fc="white", ec="k"))
    ax.plot([-MARKER_MM / 2, MARKER_MM / 2], [plane, plane], color="k", lw=3)
    ax.axhline(plane, color="tab:blue", lw=0.6, ls="--")
    ax.annotate("", (30, tip), (30, plane), arrowprops={"arrowstyle": "<->", "lw": 0.8})
    ax.text(32, (tip + plane) / 2, f"{ABOVE_TIP_MM:g} mm", va="center", fontsize=8)
    notes = [(plane + 5, f"marker plane, z {plane:g}: the cubes' top face"),
             (tip, f"tip = TCP of tool_pusher, z {tip:g} (--z)"),
             (top - held / 2, f"fingers: {held:g} mm of the {length:g} x {dia:g} mm rod")]
    for z, what in notes:
        ax.text(48, z, what, fontsize=7, va="center")
    ax.set(xlim=(-90, 150), ylim=(-8, top + 16), aspect="equal", xlabel="mm",
           ylabel="z, mm (table at 0)", title="side view at a grid point\n"
           "(calibration only: slide the cap off before trials, at push height\nits edge is at "
           "the cubes' top edge)")


def draw_mounting(out: Path) -> None:
    """The mounting drawing: both caps from above and the pusher from the side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4.8), gridspec_kw={"width_ratios": [1, 1, 1.5]})
    for ax, (arm, marker_id) in zip(axes[:2], MARKER_IDS.items(), strict=True):
        _top_view(ax, marker_id, arm)
    _side_view(axes[2])
    fig.suptitle("testbed calibrate's marker: print scripts/calibration_marker.py's caps at "
                 "100 %, glue flat on a rigid cap that slides onto the rod", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--out-dir", type=Path, default=DOCS, help="where to write (docs/)")
    p.add_argument("--ids", default="0,1", help="marker ids to print (0,1)")
    p.add_argument("--no-drawing", action="store_true", help="the caps only (no matplotlib)")
    args = p.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    for marker_id in (int(v) for v in args.ids.split(",")):
        if not 0 <= marker_id < 50:
            p.error(f"--ids: {marker_id} is not in {MARKER_DICT} (0..49)")
        path = args.out_dir / f"calibration-marker-{marker_id}.png"
        save_sheet(path, marker_sheet(marker_id))
        print(f"id {marker_id} -> {path} ({PX_PER_MM} px/mm, {PX_PER_MM * 25.4:g} DPI: print "
              f"at 100 %, the black square measures {MARKER_MM:g} mm)")
    if not args.no_drawing:
        draw_mounting(args.out_dir / "calibration-marker.png")
        print(f"drawing -> {args.out_dir / 'calibration-marker.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
