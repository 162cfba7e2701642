"""The YuMi's controller through Robot Web Services 1.0: the one controller client.

Why it looks like this: ``abb-motion-program-exec`` builds each arm's program bytes
(``MotionProgram``, format 10011) and ``abb-robot-client``'s ``RWS`` carries every request
unchanged; the upload, start and result are ours, because the library's own naming puts
both arms' programs of a MultiMove step into one file (docs/notes/rws.md). Our RAPID
(robot/rapid/) reads each task's file and reports in the event log. The same code runs
against a lab's IRC5 and against the hardware twin (``sim_twin.yumi_server``), which
answers RWS 1.0 as a controller does.

Before every start the controller's state is read (:mod:`drivers.yumi.controller_state`):
a push in manual mode, with the motors off, with RAPID running or a task stopped by a
RAPID error, with a task not holding our RAPID of the version this driver expects, or
with the world zones not proved active since the last restart
(:mod:`drivers.yumi.zones_proof`; recorded for the next agent beside the robot lock,
``zones_state_dir``) is refused with one line naming what to fix; nothing is
uploaded and nothing moves. Every event log entry since the previous program goes to the
``drivers.yumi.elog`` logger (the agent's stderr: the run's ``hosts/<host>.log``).
:meth:`stop` stops a running program of ours from another thread, on a second RWS
session, so it never waits behind the polling; the motion timeout scales with the
controller's speed ratio (a 10 % run takes ten times as long). Each robtarget's
``eax_a`` is ABB's arm angle of the joints the driver planned for it
(:meth:`RwsYumiController.program`, ``drivers/yumi/line_plan.py``); a jointtarget's is
axis 7's value.

Over 450 lines, on purpose: one class, the controller client, whose calls (the program
files, the start, the wait, the stop from another thread, the reads of the joints and
the tool) share one RWS session, its request counter and its stop flag, and must agree
on the same tasks and files; what could leave went: the reading of the controller's
state to ``controller_state.py``, the zones proof to ``zones_proof.py``, the logins to
``credentials.py``, the arm angles to ``arm_angle.py`` and ``line_plan.py``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any
from urllib.parse import urlsplit

from drivers.errors import BackendError
from drivers.yumi.controller_state import (
    _symbol,
    describe,
    entry_text,
    identity_fields,
    one_line,
    read_state,
    refusal,
    tool_frame,
    version_refusal,
)
from drivers.yumi.credentials import FACTORY_DEFAULT, RwsLogin
from drivers.yumi.yumi_controller import ArmPose, Waypoint, _since, check_result, program_file
from drivers.yumi.zones_proof import ZonesProof, proof_path
from testbed.core.addresses import is_loopback_host

elog_log = logging.getLogger("drivers.yumi.elog")
elog_log.setLevel(logging.INFO)  # the controller's own words belong in the host log
log = logging.getLogger(__name__)

TOOL = "tool_pusher"
"""Our RAPID's pusher (a ``TASK PERS tooldata`` in each task module): every motion and
every TCP read uses it, so the point read back is the point commanded."""
V_ORI_DEG_S, V_LEAX_MM_S, V_REAX_DEG_S = 100.0, 1000.0, 100.0
"""Orientation, linear and rotational external-axis speeds written into each program,
within our RAPID's caps (``tb_v_ori_max``, ``tb_v_reax_max``, ``TB_V_LEAX_MAX``: a file
above them is refused before any motion, robot/README.md)."""
POLL_S = 0.05
TOOL_LOAD = (0.272, (7.5, 11.5, 53.8), (0.0003, 0.00032, 0.00009))
"""The load the program file carries (kg, centre of gravity mm, inertia kgm2 about the
axes of tool0): the one ``tool_pusher`` ships with in robot/rapid/TestbedTask_L.mod (the
SmartGripper and the rod). Our RAPID ignores it and moves with its own ``tool_pusher``
load (robot/README.md, "The tool load"); the file says it so that it is never a
placeholder. Its frame is the calibration's ``tool_z_mm``, which the RAPID compares."""
MOTION_TASKS = ("T_ROB_L", "T_ROB_R")
"""The IRB 14000's two motion tasks: every program start gives BOTH a program (an arm
with nothing to do a "stay"), so neither replays the file its RAM disk still holds."""


def _patch_timeout(rws: Any, timeout_s: float, counter: list[int] | None = None) -> None:
    """abb-robot-client sends its requests without a timeout: a controller that accepts
    the connection and never answers would block the agent for ever. ``counter[0]``
    counts the requests."""
    session = rws._session
    plain_request = session.request

    def request(method: str, url: str, **kw: Any) -> Any:
        kw.setdefault("timeout", timeout_s)
        if counter is not None:
            counter[0] += 1
        return plain_request(method, url, **kw)

    session.request = request


def is_loopback(url: str) -> bool:
    """Whether ``url`` names this machine (the hardware twin's controller)."""
    return is_loopback_host(urlsplit(url.strip()).hostname or "")


def _login_or_factory(login: RwsLogin | None, url: str) -> RwsLogin:
    """``login``, or a one-line error: none given (no ``Default User`` fallback), or ABB's
    factory login (:data:`~drivers.yumi.credentials.FACTORY_DEFAULT`) for a controller
    that is not on this machine."""
    if login is None:
        raise BackendError(
            "credentials_file is not set: the YuMi host's credentials_file must name the "
            "controller's RWS login (a file of one line USER:PASSWORD, mode 600; robot/"
            "README.md); the agent never falls back to ABB's factory 'Default User'")
    if login.factory and not is_loopback(url):
        raise BackendError(
            f"credentials_file = {FACTORY_DEFAULT!r} (ABB's factory login) is taken only "
            f"from the hardware twin on this machine, not from {url}: give the "
            f"controller's own login file")
    return login


def controller_info(url: str, credentials_file: str | None = None,
                    timeout_s: float = 3.0) -> dict[str, str] | None:
    """The controller as it names itself: ``serial`` (``ctrl/identity``'s ``ctrl-id``),
    ``robotware`` and ``system`` (``rw/system``), only those it said; from two read-only
    RWS requests and a logout. None when the controller cannot be asked.

    Why here, before the backend: the agent keys its robot lock on the serial before it
    takes the lock (:func:`robot_identity`), and the same answer goes into its hello, so a
    run records which controller (and RobotWare) drove its arms at no further request.
    Never a credential: the login is used, not returned."""
    from abb_robot_client.rws import RWS

    from drivers.yumi.credentials import read_login

    try:  # without a login it cannot be asked (the backend's build says why)
        login = _login_or_factory(read_login(credentials_file) if credentials_file
                                  else None, url)
        rws = RWS(url.rstrip("/"), login.user, login.password)
        _patch_timeout(rws, timeout_s)
        try:
            ident = rws._do_get("ctrl/identity")
            try:
                system = rws._do_get("rw/system")
            except Exception:  # an old RobotWare: the serial alone still names the robot
                system = {}
        finally:
            with contextlib.suppress(Exception):
                rws.logout()
    except Exception:  # unreachable, refused, an old RobotWare: the URL will do
        return None
    said = {k: v for k, v in identity_fields(system, ident).items() if v}
    return said or None


def controller_tools(url: str, tasks: Sequence[str], credentials_file: str | None = None,
                     timeout_s: float = 5.0) -> dict[str, dict[str, Any] | None]:
    """Each task's ``tool_pusher`` as the controller holds it (``trans``, ``rot``, ``mass``;
    None where it cannot be read), on a session of its own: for an arm being calibrated
    whose file has no ``tool_z_mm`` yet (``drivers/yumi/backend.py``)."""
    from abb_robot_client.rws import RWS

    from drivers.yumi.credentials import read_login

    login = _login_or_factory(read_login(credentials_file) if credentials_file else None,
                              url)
    rws = RWS(url.rstrip("/"), login.user, login.password)
    _patch_timeout(rws, timeout_s)
    try:
        return {t: tool_frame(_symbol(rws, t, f"TestbedTask_{t.rsplit('_', 1)[-1]}", TOOL))
                for t in tasks}
    except Exception as exc:
        raise BackendError(f"cannot read tool_pusher from the YuMi controller: "
                           f"{one_line(exc)}") from exc
    finally:
        with contextlib.suppress(Exception):
            rws.logout()


def scaled_timeout(motion_timeout_s: float, speedratio: float | None) -> float:
    """``motion_timeout_s`` (what a program may take at 100 %) at the controller's speed
    ratio (percent, clamped to 1..100; unknown: 100): a push of 7.8 s takes 78 s at 10 %
    (docs/rws-checklist.md's 10 % runs)."""
    ratio = 100.0 if speedratio is None else min(100.0, max(1.0, float(speedratio)))
    return float(motion_timeout_s) * 100.0 / ratio


def robot_identity(info: Mapping[str, str] | None) -> str | None:
    """The robot as the lock names it, ``"IRC5 <serial>"``; None without a serial."""
    serial = (info or {}).get("serial")
    return f"IRC5 {serial}" if serial else None


def controller_identity(url: str, credentials_file: str | None = None,
                        timeout_s: float = 3.0) -> str | None:
    """The robot as its controller names itself, ``"IRC5 <serial>"``, from
    :func:`controller_info`; None when the controller cannot be asked (the caller then
    locks on the URL): two spellings of one address are one robot."""
    return robot_identity(controller_info(url, credentials_file, timeout_s))


class RwsYumiController:
    """Both arms of an IRB 14000 through RWS; programs of both arms start together."""

    def __init__(self, base_url: str, arms: Mapping[str, ArmPose], *,
                 login: RwsLogin | None = None, http_timeout_s: float = 5.0,
                 motion_timeout_s: float = 15.0,
                 zones_state_dir: str | os.PathLike[str] | None = None) -> None:
        # Lazy: these clients pull in requests/websockets; only a YuMi host needs them.
        from abb_motion_program_exec import abb_motion_program_exec_client as mpe
        from abb_robot_client.rws import RWS

        login = _login_or_factory(login, base_url)
        self._mpe: Any = mpe
        self._arms = dict(arms)
        self._motion_timeout_s = motion_timeout_s
        self.timeout_s = motion_timeout_s
        """The last start's motion timeout: ``motion_timeout_s`` scaled by the speed
        ratio the controller said at that start (:func:`scaled_timeout`)."""
        self._seqno = 0
        self._rws: Any = RWS(base_url, login.user, login.password)
        self._stop_rws: Any = RWS(base_url, login.user, login.password)
        self._count = [0]
        _patch_timeout(self._rws, http_timeout_s, self._count)
        _patch_timeout(self._stop_rws, min(http_timeout_s, 1.0))
        self._stopping = threading.Event()
        self._moving = threading.Event()
        """Set once one of our programs IS started (``rws.start`` returned) until RAPID is
        seen stopped: only then is a running program ours, and :meth:`stop` stops it."""
        self._zones = ZonesProof(self.tasks())
        """The proof, kept across reads of the event log, that the zones are on."""
        self._zones_dir = zones_state_dir
        """Where the proof is recorded for the next agent (the robot lock's folder;
        None: not recorded, a proof from the log alone at every driver's start)."""
        self._zones_file: tuple[str, str] | None = None
        """(path, serial) of the proof file, once the first start or report read the
        serial."""
        self._zones_resumed = False
        self._last_entry: int | None = None
        self._ramdisk: str | None = None
        self._idle_tools: dict[str, float] = {}
        self.timing: dict[str, float] = {}
        """Wall seconds of the last :meth:`execute`'s phases: ``checks`` (event log and
        state reads), ``upload`` (resetpp, RAM disk path, the files), ``start``, ``wait``
        (the motion, polled until RAPID stops) and ``log`` (the result's entries)."""

    @property
    def requests(self) -> int:
        """HTTP requests sent on the main session so far (the benchmark and the notes
        count a push's from it)."""
        return self._count[0]

    def program(self, arm: str, waypoints: Sequence[Waypoint],
                start_joints: Sequence[float] | None = None) -> Any:
        """The ``MotionProgram`` of one arm (public for tests: its RAPID can be read). A
        joint target (``rest``: the arm's rest joints; ``abs_j``: the waypoint's, the
        gate's) is a MoveAbsJ, axis 7 as the jointtarget's first external axis
        (``eax_a``, as the controller reports it in ``get_jointtarget``). A robtarget's
        ``eax_a`` is ABB's arm angle, not axis 7 (docs/notes/rws.md): each carries the
        arm angle of the joints the driver planned for it
        (:func:`drivers.yumi.line_plan.planned_targets`: its inverse kinematics at the
        calibration's arm angle ``arm_angle_deg``, from the joints before), the plan the
        layout check sweeps; planned from ``start_joints`` (ABB's order; default: the
        arm's joints as the controller reports them, read only when a robtarget comes
        before any joint target). An arm the model cannot plan for (not an IRB 14000
        arm, a target out of its reach) is refused: nothing is sent."""
        from drivers.yumi.line_plan import planned_targets
        from drivers.yumi.reach import ArmTool, default_arm_angle, side_of

        mpe = self._mpe
        pose = self._arms[arm]
        mp = mpe.MotionProgram(tool=self._tool(arm, pose.tool_z_mm))
        side = side_of(arm, pose.task)
        if side is None:
            raise BackendError(f"arm {arm}: task {pose.task} is not an IRB 14000 arm's; the "
                               f"driver cannot tell its robtargets' arm angle; nothing is sent")
        angle = pose.arm_angle_deg if pose.arm_angle_deg is not None else \
            default_arm_angle(side)
        tool = ArmTool(side, float(pose.tool_z_mm or 0.0), angle,
                       tuple(float(v) for v in pose.tool_quat_wxyz))
        start = None
        first = next((w for w in waypoints if w.kind in ("rest", "abs_j", "move_j",
                                                         "move_l")), None)
        if first is not None and first.kind in ("move_j", "move_l"):
            here = start_joints if start_joints is not None else self.joints()[arm]
            start = tool.model.pose_abb(here).chain_deg
        plan, why = planned_targets(tool, start, pose.rest_joints_deg, waypoints)
        if why is not None:
            raise BackendError(f"arm {arm}: the driver cannot plan its program: {why}; "
                               f"nothing is sent")
        for w, target in zip(waypoints, plan, strict=True):
            speed = mpe.speeddata(float(w.speed_mm_s), V_ORI_DEG_S, V_LEAX_MM_S, V_REAX_DEG_S)
            zone = mpe.fine if w.fine else mpe.z10
            if w.kind in ("rest", "abs_j"):
                j = pose.rest_joints_deg if w.kind == "rest" else w.joints_deg
                assert j is not None and len(j) == 7  # planned_targets refused it else
                mp.MoveAbsJ(mpe.jointtarget([float(v) for v in j[:6]],
                                            [float(j[6]), 9e9, 9e9, 9e9, 9e9, 9e9]),
                            speed, zone)
                continue
            assert w.xyz_mm is not None and target.arm_angle_deg is not None
            extax = [round(target.arm_angle_deg, 4), 9e9, 9e9, 9e9, 9e9, 9e9]
            rob = mpe.robtarget(list(w.xyz_mm), list(pose.tool_quat_wxyz),
                                mpe.confdata(*pose.robconf), extax)
            (mp.MoveJ if w.kind == "move_j" else mp.MoveL)(rob, speed, zone)
        return mp

    def _tool(self, arm: str, tool_z_mm: float | None) -> Any:
        """The tooldata a program file carries: the calibration's frame (never a silent
        flange: a pose without ``tool_z_mm`` is an error) and :data:`TOOL_LOAD`."""
        if tool_z_mm is None:
            raise BackendError(f"arm {arm}: no tool_z_mm (the pusher's length) to send; "
                               f"the calibration file must give it (robot/README.md, 'The "
                               f"tool frame')")
        mpe = self._mpe
        mass, cog, (ix, iy, iz) = TOOL_LOAD
        return mpe.tooldata(True, mpe.pose([0, 0, float(tool_z_mm)], [1, 0, 0, 0]),
                            mpe.loaddata(mass, list(cog), [1, 0, 0, 0], ix, iy, iz))

    def stay(self, task: str) -> Any:
        """The program of a task with nothing to do: one ``WaitTime 0`` (our RAPID runs it
        and writes its Done entry; nothing moves), with the task's arm's tool frame, or,
        for a task no arm of this host drives, the controller's own ``tool_pusher``."""
        arm = next((a for a, p in self._arms.items() if p.task == task), None)
        if arm is not None:
            tool = self._tool(arm, self._arms[arm].tool_z_mm)
        else:
            if task not in self._idle_tools:
                frame = tool_frame(_symbol(self._rws, task,
                                           f"TestbedTask_{task.rsplit('_', 1)[-1]}", TOOL))
                if frame is None:
                    raise BackendError(f"YuMi controller: cannot read tool_pusher of task "
                                       f"{task} for its stay program; is the testbed RAPID "
                                       f"loaded? (robot/README.md)")
                self._idle_tools[task] = frame["trans"][2]
            tool = self._tool(task, self._idle_tools[task])
        mp = self._mpe.MotionProgram(tool=tool)
        mp.WaitTime(0)
        return mp

    def tasks(self) -> list[str]:
        """Every task a start runs: the arms' and the other IRB 14000 motion task."""
        mine = [p.task for p in self._arms.values()]
        extra = [t for t in MOTION_TASKS if t not in mine] if set(mine) <= set(
            MOTION_TASKS) else []
        return mine + extra

    def execute(self, programs: Mapping[str, Sequence[Waypoint]]) -> None:
        """Run ``programs`` (arm -> waypoints) at once. EVERY motion task gets a program:
        an arm not in ``programs`` (and a task no arm of this host drives) gets a
        :meth:`stay`, so no task replays the file its RAM disk still holds (a controller
        that omits ``motiontask`` lets abb_robot_client's start() run every task); both
        tasks must report Done for this program (:func:`check_result`)."""
        if not any(a in programs for a in self._arms):
            return
        mps = {self._arms[a].task: self.program(a, programs[a]) for a in self._arms
               if a in programs}
        mps.update({t: self.stay(t) for t in self.tasks() if t not in mps})
        self._seqno = self._seqno % 60000 + 1  # float32-exact, and new for every step
        seqno = self._seqno
        self._stopping.clear()
        try:
            self._execute(mps, seqno)
        finally:
            self._moving.clear()

    def _execute(self, mps: Mapping[str, Any], seqno: int) -> None:
        self.timing = {}
        prev: int | None = None
        try:
            prev = self._start(mps, seqno)
            t0 = time.perf_counter()
            self._wait()
            t1 = time.perf_counter()
            entries = self._entries_since(prev)
            self.timing.update(wait=t1 - t0, log=time.perf_counter() - t1)
        except BackendError:
            with contextlib.suppress(Exception):  # the controller's side of the failure
                self._entries_since(prev)
            raise
        except Exception as exc:
            raise BackendError(f"YuMi controller refused the motion program: "
                               f"{one_line(exc)}") from exc
        check_result(entries, list(mps), seqno)

    def _start(self, mps: Mapping[str, Any], seqno: int) -> int | None:
        """Refuse unless the controller is ready, every task holds our RAPID of the
        version this driver expects (read now, for EVERY task started) and every task's
        zones are proved active since the last restart; activate every task (ourselves:
        the client's start() does not when the controller omits ``motiontask``), THEN
        reset the program pointers (a task activated after ``resetpp`` would start where
        it stopped), upload every task's program to ITS file and start them together,
        unless a stop came meanwhile. Returns the newest event log entry before."""
        rws = self._rws
        t0 = time.perf_counter()
        if not self._zones_resumed:
            self._resume_zones()
        log_before = rws.read_event_log()
        prev = log_before[0].seqnum if log_before else None
        self._log_new(log_before)
        zones = self._zones.read(log_before)  # every read: the proof sees every entry
        state = read_state(rws, log_before)
        why = refusal(state) or version_refusal(rws, list(mps)) or zones
        if why is not None:
            raise BackendError(f"YuMi controller: {why}; the motion was not started")
        self.timeout_s = scaled_timeout(self._motion_timeout_s, state.speedratio)
        t1 = time.perf_counter()
        for task in mps:
            rws.activate_task(task)
        rws.resetpp()
        if self._ramdisk is None:  # the controller's RAM disk folder does not move
            self._ramdisk = str(rws.get_ramdisk_path())
        for task, mp in mps.items():
            rws.upload_file(f"{self._ramdisk}/{program_file(task)}",
                            mp.get_program_bytes(seqno))
        t2 = time.perf_counter()
        if self._stopping.is_set():  # a stop before the start: prevent it, touch nothing
            raise BackendError("YuMi controller: the motion was stopped before it started "
                               "(the operator stopped the trial or the link to the "
                               "controller was lost); the motion was not started")
        rws.start(cycle="once", tasks=list(mps))
        self._moving.set()  # ours from here: a stop now ends it
        if self._stopping.is_set():  # a stop that came while the start was sent
            self._stop_ours()
        self.timing.update(checks=t1 - t0, upload=t2 - t1, start=time.perf_counter() - t2)
        return prev

    def _wait(self) -> None:
        """Poll until RAPID stops; our program ends there, and so does :meth:`stop`'s
        right to stop what runs (a person's program started after ours is theirs)."""
        deadline = time.monotonic() + self.timeout_s
        while self._rws.get_execution_state().ctrlexecstate == "running":
            if self._stopping.is_set():
                raise BackendError("YuMi controller: the motion was stopped (the operator "
                                   "stopped the trial or the link to the controller was lost)")
            if time.monotonic() > deadline:
                self._rws.stop()
                raise BackendError(
                    f"YuMi controller: the motion did not finish within motion_timeout_s = "
                    f"{self._motion_timeout_s:g} s scaled to the speed ratio "
                    f"({self.timeout_s:g} s); the program was stopped")
            time.sleep(POLL_S)
        self._moving.clear()
        if self._stopping.is_set():
            raise BackendError("YuMi controller: the motion was stopped (the operator "
                               "stopped the trial or the link to the controller was lost)")

    def _entries_since(self, prev: int | None) -> list[Any]:
        log_now = self._rws.read_event_log()
        self._log_new(log_now)
        self._zones.read(log_now)  # the proof sees this read too: fewer entries to miss
        self._record_zones()  # once per start: the newest entry for the next agent
        return _since(log_now, prev)

    def _resume_zones(self) -> None:
        """At the first start or report: the controller's serial (``ctrl/identity``), and the proof
        the agent before recorded for it (:meth:`ZonesProof.load`); none taken (no
        state folder, no serial, no file, one not to trust): the log alone proves."""
        self._zones_resumed = True
        if self._zones_dir is None:
            return
        try:
            serial = identity_fields({}, self._rws._do_get("ctrl/identity"))["serial"]
        except Exception as exc:  # the proof then comes from the log alone
            log.warning("zones proof not recorded: cannot read the controller's serial: %s",
                        one_line(exc))
            return
        if not serial:
            log.warning("zones proof not recorded: the controller names no serial")
            return
        path = str(proof_path(self._zones_dir, serial))
        self._zones_file = (path, serial)
        if (why := self._zones.load(path, serial)) is None:
            log.info("continuing the zones proof recorded in %s", path)
        else:
            log.log(logging.INFO if why.startswith("no ") else logging.WARNING,
                    "%s; the event log alone must show the zones", why)

    def _record_zones(self) -> None:
        """Record the proof for the next agent (:meth:`ZonesProof.save`); a failure is
        logged and leaves the last record (an older one is continued as safely)."""
        if self._zones_file is None:
            return
        path, serial = self._zones_file
        try:
            self._zones.save(path, serial)
        except OSError as exc:
            log.warning("cannot record the zones proof in %s: %s", path, exc)

    def _log_new(self, log_now: Sequence[Any]) -> None:
        """Every entry not logged yet, oldest first, to the host log (one line each)."""
        fresh = _since(log_now, self._last_entry) if self._last_entry is not None else []
        for e in fresh:
            level = logging.WARNING if e.msgtype >= 3 else logging.INFO
            elog_log.log(level, "controller %s (seq %d, type %d)", entry_text(e), e.seqnum,
                         e.msgtype)
        if log_now:
            self._last_entry = log_now[0].seqnum

    def stop(self) -> None:
        """Stop OUR program now (from another thread than :meth:`execute`'s). With none of
        ours running, nothing is sent: a program a person started from the FlexPendant is
        theirs, and an agent told to stop as it exits (its link closed during a refused
        rest at bye) must not end it behind their back: the next push is refused with
        "RAPID is running", as the person would expect. No window: a program is ours
        only once ``rws.start`` returned; a stop before that makes :meth:`_start` start
        nothing, one while the start is sent is carried out by :meth:`_start` itself (the
        flag is set, then the stop read; here the stop is set, then the flag read: one of
        the two always sees the other)."""
        self._stopping.set()
        if not self._moving.is_set():  # not started yet: _start sees the flag, starts nothing
            return
        self._stop_ours()

    def _stop_ours(self) -> None:
        """Stop RAPID on the stop session: only called while our program runs."""
        try:
            self._stop_rws.stop()
        except Exception as exc:  # the polling loop still ends on the flag
            log.error("could not stop RAPID through RWS: %s", one_line(exc))

    def tcp_xyz(self) -> dict[str, tuple[float, float, float]]:
        out: dict[str, tuple[float, float, float]] = {}
        try:
            for arm, pose in self._arms.items():
                rt = self._rws.get_robtarget(mechunit=pose.mechunit, tool=TOOL, wobj="wobj0",
                                             coordinate="Wobj")
                out[arm] = (float(rt.trans[0]), float(rt.trans[1]), float(rt.trans[2]))
        except Exception as exc:
            raise BackendError(f"cannot read the arms' positions ({TOOL} in wobj0) from the "
                               f"YuMi controller: {one_line(exc)}") from exc
        return out

    def joints(self) -> dict[str, tuple[float, ...]]:
        """Every arm's joints as the controller reports them (``get_jointtarget``: axes
        1-6 in ``robax``, axis 7 in the first external axis), ABB's order, degrees."""
        out: dict[str, tuple[float, ...]] = {}
        try:
            for arm, pose in self._arms.items():
                jt = self._rws.get_jointtarget(mechunit=pose.mechunit)
                out[arm] = (*(float(v) for v in list(jt.robax)[:6]), float(jt.extax[0]))
        except Exception as exc:
            raise BackendError(f"cannot read the arms' joints (jointtarget) from the YuMi "
                               f"controller: {one_line(exc)}") from exc
        return out

    def describe(self) -> dict[str, Any]:
        """``testbed check``'s report (:func:`describe`). The zones are judged as a start
        judges them: the log read here also goes into the kept proof (continued from the
        agent before, as at a first start, and recorded), and a task the log alone no
        longer shows proved (rolled past its restart entry) is reported with the proof
        (:meth:`ZonesProof.known`). Without it, a check after a day of pushes refused
        the trial the driver would run."""
        try:
            if not self._zones_resumed:
                self._resume_zones()
            log_now = self._rws.read_event_log()
            self._log_new(log_now)
            self._zones.read(log_now)
            self._record_zones()
            rep = describe(self._rws, [p.task for p in self._arms.values()], log_now)
            for task, ours in rep.rapid.items():
                if not ours["zones_known"]["known"] and (kept := self._zones.known(task)):
                    ours["zones_known"] = kept
            return rep.to_dict()
        except Exception as exc:
            raise BackendError(f"cannot read the YuMi controller's state: "
                               f"{one_line(exc)}") from exc

    def close(self) -> None:
        for rws in (self._rws, self._stop_rws):
            with contextlib.suppress(Exception):  # best effort on the way out
                rws.logout()
