"""Which V4L2 node is the host's camera: by index, by path or by card name.

Why a module of its own: a lab writes ``camera = "0"``, ``"/dev/video4"``, a stable
``/dev/v4l/by-id/...`` or ``/dev/v4l/by-path/...`` link, or the camera's name, and one
USB camera is several nodes. A UVC webcam has a capture node and a metadata node under
one name; a RealSense has depth, infrared and colour streams (each with a metadata
node), the depth stream first, so ``camera = "0"`` is a depth picture. OpenCV opens any
node it is given (a depth stream shows as a grey picture), so the node is chosen, or
refused, here, from what the kernel says about it, before OpenCV opens it.

What is known of a node (:class:`V4l2Node`): its card name and its index within its
device (``/sys/class/video4linux/videoN/name`` and ``index``), the physical (USB) device
it belongs to (``.../videoN/device``, the interface's parent), and its *kind*:

1. asked of the kernel when the node answers (``VIDIOC_QUERYCAP``: a node that cannot
   capture video is ``metadata``; ``VIDIOC_ENUM_FMT``: any colour pixel format (YUYV,
   MJPG, RGB3, NV12, a Bayer format...) makes it ``colour``, else Z16 and its kin
   ``depth``, else GREY/Y8I/Y12I/Y16 ``grey`` (infrared, or a monochrome camera));
2. else from the card name's words: "RGB", "Color" or "Colour" anywhere is ``colour``
   (so "... Depth Camera 435i RGB" is colour), "IR" or "Infrared" is ``grey``, a name
   ending in "Depth" is ``depth`` (a driver that names its streams);
3. else ``unknown`` (a stock UVC RealSense names all six nodes "Intel(R) RealSense(TM)
   Depth Ca": only the kernel's formats tell them apart).

The rule for a card name (:meth:`V4l2Devices.by_card`): the nodes whose name equals it
(case and surrounding spaces ignored), else those whose name contains it; of those the
``colour`` ones, else the ``unknown`` ones (depth, grey and metadata nodes are never
chosen); they must belong to one physical device (two identical webcams: an error that
lists each one's by-id/by-path link); of that device's, the lowest node index (a
webcam's capture node comes before its metadata node). A node given by index or path
is opened as given, unless it is known to be depth, grey or metadata: then an error
names the same device's colour node.
"""

from __future__ import annotations

import contextlib
import os
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from drivers.errors import BackendError

DEV_ROOT = "/dev"
SYSFS_ROOT = "/sys/class/video4linux"

COLOUR = "colour"
DEPTH = "depth"
GREY = "grey"
METADATA = "metadata"
UNKNOWN = "unknown"
NOT_COLOUR = (DEPTH, GREY, METADATA)

COLOUR_FORMATS = frozenset({
    "YUYV", "YVYU", "UYVY", "VYUY", "MJPG", "JPEG", "RGB3", "BGR3", "RGB4", "BGR4", "XR24",
    "AR24", "XB24", "AB24", "RGBP", "NV12", "NV21", "NV16", "NV61", "YU12", "YV12", "422P",
    "411P", "BA81", "GBRG", "GRBG", "RGGB", "S910", "H264", "HEVC"})
"""Pixel formats of a colour picture (V4L2 FOURCCs)."""
DEPTH_FORMATS = frozenset({"Z16 ", "Z16H", "INVZ", "INZI", "INVR", "INRI"})
"""Depth formats (RealSense and its kin)."""
GREY_FORMATS = frozenset({"GREY", "Y8  ", "Y8I ", "Y10 ", "Y10B", "Y12 ", "Y12I", "Y16 ",
                          "Y16I"})
"""Greyscale formats: an infrared stream, or a monochrome camera."""

VIDIOC_QUERYCAP = 0x80685600
"""_IOR('V', 0, struct v4l2_capability): 104 bytes."""
VIDIOC_ENUM_FMT = 0xC0405602
"""_IOWR('V', 2, struct v4l2_fmtdesc): 64 bytes."""
CAP_VIDEO_CAPTURE = 0x00000001
CAP_VIDEO_CAPTURE_MPLANE = 0x00001000
CAP_DEVICE_CAPS = 0x80000000
BUF_TYPE_VIDEO_CAPTURE = 1
BUF_TYPE_VIDEO_CAPTURE_MPLANE = 9

_NODE = re.compile(r"video(\d+)")
_USB_INTERFACE = re.compile(r"\d+-[\d.]+:\d+\.\d+")


@dataclass(frozen=True, slots=True)
class NodeFacts:
    """What the kernel answered about a node: can it capture video, in which formats."""

    video_capture: bool
    formats: tuple[str, ...]


NodeProbe = Callable[[str], "NodeFacts | None"]
"""``probe(path) -> NodeFacts | None`` (None: the node does not answer): the seam where the
kernel is asked; the tests stand a function in for it (a temp file answers no ioctl)."""


def fourcc_text(code: int) -> str:
    """A FOURCC integer (OpenCV's ``CAP_PROP_FOURCC``, V4L2's pixelformat) as 4 characters."""
    code = int(code) & 0x7FFFFFFF  # bit 31: V4L2's big-endian flag
    return bytes((code >> (8 * i)) & 0xFF for i in range(4)).decode("latin-1")


def query_node(path: str) -> NodeFacts | None:
    """Ask the kernel about a node (QUERYCAP, then ENUM_FMT of its capture type).

    Why ioctls and not OpenCV: OpenCV opens a depth node happily and converts Z16 to a
    grey picture; the formats a node offers are what tells depth, infrared and colour
    apart when the card names are all the same. None when the node does not answer (not
    a V4L2 node, no permission): the caller then goes by the card name.
    """
    import fcntl

    try:
        fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        cap = bytearray(104)
        fcntl.ioctl(fd, VIDIOC_QUERYCAP, cap, True)
        caps, device_caps = struct.unpack_from("=II", cap, 84)
        caps = device_caps if caps & CAP_DEVICE_CAPS else caps
        if not caps & (CAP_VIDEO_CAPTURE | CAP_VIDEO_CAPTURE_MPLANE):
            return NodeFacts(False, ())
        buf_type = (BUF_TYPE_VIDEO_CAPTURE if caps & CAP_VIDEO_CAPTURE
                    else BUF_TYPE_VIDEO_CAPTURE_MPLANE)
        formats: list[str] = []
        for i in range(64):
            desc = bytearray(64)
            struct.pack_into("=II", desc, 0, i, buf_type)
            try:
                fcntl.ioctl(fd, VIDIOC_ENUM_FMT, desc, True)
            except OSError:
                break  # EINVAL after the last format
            formats.append(fourcc_text(struct.unpack_from("=I", desc, 44)[0]))
        return NodeFacts(True, tuple(formats))
    except OSError:
        return None
    finally:
        os.close(fd)


def kind_of(facts: NodeFacts | None, card: str) -> tuple[str, str]:
    """(kind, why) of a node: the kernel's answer first, else the card name's words."""
    if facts is not None:
        if not facts.video_capture:
            return METADATA, "the kernel: not a video capture node"
        fmts = set(facts.formats)
        shown = ", ".join(f.strip() for f in facts.formats) or "none"
        for kind, group in ((COLOUR, COLOUR_FORMATS), (DEPTH, DEPTH_FORMATS),
                            (GREY, GREY_FORMATS)):
            if fmts & group:
                return kind, f"formats {shown}"
        return UNKNOWN, f"formats {shown}"
    words = re.findall(r"[a-z0-9]+", card.lower())
    if {"rgb", "color", "colour"} & set(words):
        return COLOUR, "its card name"
    if {"ir", "infrared"} & set(words):
        return GREY, "its card name"
    if words and words[-1] == "depth":
        return DEPTH, "its card name"
    return UNKNOWN, "neither the kernel nor the card name says"


@dataclass(frozen=True, slots=True)
class V4l2Node:
    """One ``/dev/videoN`` and what is known of it (module docstring)."""

    number: int
    path: str
    card: str
    index: int | None
    """The node's number within its device (sysfs ``index``); None when unknown."""
    device: str | None
    """The physical device it belongs to (a sysfs path), None when unknown."""
    kind: str
    why: str
    """How ``kind`` was decided, for messages."""

    def label(self) -> str:
        """``/dev/video4 ('HD Pro Webcam C920')``, for messages and logs."""
        return f"{self.path} ({self.card!r})" if self.card else self.path


class V4l2Devices:
    """The V4L2 nodes of this host. ``dev_root``, ``sysfs_root`` and ``probe`` are seams:
    the tests build a ``/dev`` and a ``/sys/class/video4linux`` under a temp folder and
    answer for the kernel (a real node cannot exist on a CI machine)."""

    def __init__(self, dev_root: str = DEV_ROOT, sysfs_root: str = SYSFS_ROOT,
                 probe: NodeProbe | None = None) -> None:
        self.dev_root = dev_root
        self.sysfs_root = sysfs_root
        self._probe: NodeProbe = query_node if probe is None else probe

    def is_device_path(self, source: str) -> bool:
        """A source under the device root (``/dev/...``) names a device node, never a file."""
        root = os.path.join(os.path.abspath(self.dev_root), "")
        return os.path.abspath(source).startswith(root)

    def _read(self, number: int, name: str) -> str | None:
        with contextlib.suppress(OSError, UnicodeDecodeError):
            return (Path(self.sysfs_root) / f"video{number}" / name).read_text(
                encoding="utf-8").strip()
        return None

    def _physical(self, number: int) -> str | None:
        link = Path(self.sysfs_root) / f"video{number}" / "device"
        if not link.exists():
            return None
        target = Path(os.path.realpath(link))
        return str(target.parent if _USB_INTERFACE.fullmatch(target.name) else target)

    def node(self, number: int) -> V4l2Node:
        """``/dev/video<number>`` as sysfs and the kernel describe it (unknowns when silent)."""
        path = os.path.join(self.dev_root, f"video{number}")
        card = self._read(number, "name") or ""
        raw_index = self._read(number, "index")
        index = int(raw_index) if raw_index is not None and raw_index.isdigit() else None
        facts = self._probe(path) if os.path.exists(path) else None
        kind, why = kind_of(facts, card)
        return V4l2Node(number, path, card, index, self._physical(number), kind, why)

    def numbers(self) -> list[int]:
        """The node numbers of this host: sysfs's, else the device root's ``videoN``."""
        for root in (self.sysfs_root, self.dev_root):
            with contextlib.suppress(OSError):
                found = [int(m.group(1)) for e in os.listdir(root)
                         if (m := _NODE.fullmatch(e))]
                if found:
                    return sorted(found)
        return []

    def nodes(self) -> list[V4l2Node]:
        return [self.node(n) for n in self.numbers()]

    def links(self, node: V4l2Node) -> list[str]:
        """The stable names of a node: ``<dev>/v4l/by-id/*`` and ``by-path/*`` links to it."""
        target = os.path.realpath(node.path)
        out = []
        for sub in ("by-id", "by-path"):
            folder = Path(self.dev_root) / "v4l" / sub
            with contextlib.suppress(OSError):
                out += sorted(str(p) for p in folder.iterdir()
                              if os.path.realpath(p) == target)
        return out

    def by_number(self, number: int, asked: str) -> V4l2Node:
        """The node ``/dev/video<number>``, refused if it is known not to be colour."""
        node = self.node(number)
        self._refuse_non_colour(node, asked)
        return node

    def by_path(self, path: str) -> V4l2Node:
        """A ``/dev/videoN`` path or any symlink to one (``/dev/v4l/by-id/...``)."""
        if not os.path.lexists(path):
            folder = Path(path).parent
            with contextlib.suppress(OSError):
                there = sorted(p.name for p in folder.iterdir())
                raise BackendError(f"camera {path}: no such device (unplugged?); {folder} "
                                   f"has: {', '.join(there) or 'nothing'}")
            raise BackendError(f"camera {path}: no such device (unplugged?)")
        real = os.path.realpath(path)
        m = _NODE.fullmatch(os.path.basename(real))
        if m is None or os.path.dirname(real) != os.path.realpath(self.dev_root):
            raise BackendError(f"camera {path}: not a V4L2 video node (it is {real}); give "
                               f"/dev/videoN or a /dev/v4l/by-id or by-path link")
        return self.by_number(int(m.group(1)), path)

    def _refuse_non_colour(self, node: V4l2Node, asked: str) -> None:
        if node.kind not in NOT_COLOUR:
            return
        colour = [n for n in self.nodes() if n.kind == COLOUR and n.device is not None
                  and n.device == node.device]
        fix = (f"its device's colour stream is {colour[0].path}: set camera = "
               f"\"{colour[0].path}\" or its card name" if colour else
               "give the colour stream's node or its card name")
        raise BackendError(f"camera {asked!r}: {node.label()} is a {node.kind} stream "
                           f"({node.why}), not a colour picture; {fix}")

    def by_card(self, name: str) -> V4l2Node | None:
        """The colour node of the device whose card name is ``name`` (module docstring's
        rule); None when no node has that name."""
        nodes = self.nodes()
        want = name.strip().casefold()
        matched = ([n for n in nodes if n.card.strip().casefold() == want]
                   or [n for n in nodes if want and want in n.card.casefold()])
        if not matched:
            return None
        chosen = ([n for n in matched if n.kind == COLOUR]
                  or [n for n in matched if n.kind == UNKNOWN])
        if not chosen:
            kinds = ", ".join(f"{n.path} {n.kind}" for n in matched)
            raise BackendError(f"camera {name!r}: that device has no colour stream ({kinds})")
        devices = {n.device or n.path for n in chosen}
        if len(devices) > 1:
            each = "; ".join(f"{n.label()}: {', '.join(self.links(n)) or 'no stable link'}"
                             for n in chosen)
            raise BackendError(f"camera {name!r}: {len(devices)} devices have that name; "
                               f"name one by its /dev/v4l/by-id or by-path link ({each})")
        return min(chosen, key=lambda n: (n.index if n.index is not None else 0, n.number))

    def listing(self) -> str:
        """``video0 'C920' colour, video1 'C920' metadata`` (what an error shows)."""
        return ", ".join(f"video{n.number} {n.card!r} {n.kind}" for n in self.nodes()) \
            or "no V4L2 nodes"
