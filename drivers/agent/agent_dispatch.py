"""What the agent's worker does with one ordered request: the backend's call, its reply.

Why apart: the verbs of the wire protocol (``drivers/wire.py``) meet the five calls and
the optional capabilities of ``HostBackend`` here, and nowhere else; a backend's
exception becomes an error frame (a ``BackendError``, an expected refusal: its message
alone; anything else with its traceback), never the end of the agent.
"""

from __future__ import annotations

import logging
import traceback
from typing import TYPE_CHECKING

from drivers import wire as p
from drivers.backends.base import ArmView
from drivers.errors import BackendError

if TYPE_CHECKING:
    from drivers.backends.base import HostBackend

__all__ = ["dispatch"]

log = logging.getLogger("drivers.agent")

_CANNOT: dict[str, str] = {
    "reseed": "be reseeded", "frame": "take a full camera frame",
    "move_tcp": "move a TCP to a point", "save_calibration": "save a calibration",
    "describe": "describe a robot controller"}


def _observe_reply(backend: HostBackend, mid: int) -> bytes:
    """Views for the arms that have one; the others' errors (that arm alone faults).

    A backend says an arm has no view by leaving it out, or by giving an exception or a
    :class:`~drivers.wire.ArmFailed` in its place."""
    got: dict[str, object] = dict(backend.observe())
    views: dict[str, ArmView] = {}
    errors: dict[str, str] = {}
    for arm in backend.arm_names:
        v = got.get(arm)
        if isinstance(v, ArmView):
            views[arm] = v
        elif isinstance(v, p.ArmFailed):
            errors[arm] = v.error
        elif isinstance(v, BaseException):
            errors[arm] = f"{type(v).__name__}: {v}"
        else:
            errors[arm] = f"the backend returned no view for arm {arm!r}"
    return p.make_observe_reply(mid, views, errors)


def dispatch(backend: HostBackend, req: p.Request) -> bytes:
    """The reply to one ordered request; a backend's exception becomes an error frame:
    a ``BackendError`` (an expected refusal) with its message alone, anything else with
    its traceback, for the operator's log."""
    try:
        if req.type == "observe":
            return _observe_reply(backend, req.id)
        if req.type == "push":
            return p.make_push_reply(req.id, backend.push(req.body["faces"]))
        if req.type == "reset":
            return p.make_reset_reply(req.id, backend.reset(req.body["arms"]))
        if req.type == "rest":
            backend.rest()
            return p.encode_frame({"type": "rest_ok", "id": req.id})
        if req.type == "reseed":
            backend.reseed(req.body["seed"])
            return p.encode_frame({"type": "reseed_ok", "id": req.id})
        if req.type == "frame":
            return p.make_frame_reply(req.id, backend.frame())
        if req.type == "move_tcp":
            tcp = backend.move_tcp(req.body["arm"], req.body["xyz_mm"])
            return p.encode_frame({"type": "move_tcp_ok", "id": req.id,
                                   "tcp": [float(v) for v in tcp]})
        if req.type == "save_calibration":
            path = backend.save_calibration(req.body["arm"], req.body["data"])
            return p.encode_frame({"type": "save_calibration_ok", "id": req.id,
                                   "path": str(path)})
        if req.type == "describe":
            return p.encode_frame({"type": "describe_ok", "id": req.id,
                                   "info": backend.describe()})
        return p.make_error(req.id, "protocol", f"unhandled request {req.type!r}")
    except NotImplementedError as exc:
        what = _CANNOT.get(req.type, f"do {req.type!r}")
        return p.make_error(req.id, "request", f"this backend ({backend.kind}) cannot {what}"
                            f"{f': {exc}' if str(exc) else ''}", arm=req.body.get("arm"))
    except ValueError as exc:
        return p.make_error(req.id, "request", str(exc), traceback=traceback.format_exc(),
                            arm=getattr(exc, "arm", None))
    except BackendError as exc:  # an expected refusal: one line for the operator
        log.warning("%s refused: %s", req.type, exc)
        return p.make_error(req.id, "backend", str(exc) or type(exc).__name__,
                            arm=getattr(exc, "arm", None))
    except Exception as exc:  # the controller decides; we keep serving
        log.exception("%s failed", req.type)
        return p.make_error(req.id, "backend", f"{type(exc).__name__}: {exc}",
                            traceback=traceback.format_exc(), arm=getattr(exc, "arm", None))
