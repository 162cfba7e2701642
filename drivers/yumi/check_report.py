"""What ``testbed check`` prints of a YuMi's controller and camera, and what it fails on.

Why here, with the YuMi: the report is the YuMi's (RobotWare, options, tasks, our RAPID
and its world zones, a V4L2 camera's settings and each crop's picture quality);
``testbed check`` asks any backend with the ``controller`` capability for its report
(``testbed.core.backend_registry.Backend.controller_report``) and prints it as given.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["camera_lines", "controller_report", "layout_report", "report_lines"]


def controller_report(name: str, info: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    """(report lines, FAULT reasons) of host ``name``'s ``describe()`` answer: anything
    that would refuse a push or stop an arm (manual mode, motors off, a guard stop, a
    program running, a RAPID error, a missing option or module, a table box wider than
    its world zone) is a reason to fix first."""
    from drivers.yumi.controller_state import RAPID_VERSION, option_warnings, problems

    rep, boxes = info["controller"], info.get("table_boxes", {})
    lines = report_lines(name, rep, RAPID_VERSION, info.get("tool_z"), info.get("max_speed"))
    lines += [f"WARN  {name}: {w}" for w in option_warnings(rep)]
    lines += camera_lines(name, info.get("camera") or {})
    faults = problems(rep, list(rep.get("rapid", {})), boxes, info.get("travel_z"),
                      info.get("clear_z"), info.get("tool_z"), info.get("max_speed"))
    got, bad = layout_report(rep, info)
    return lines + got, faults + bad


def layout_report(rep: Mapping[str, Any], info: Mapping[str, Any]
                  ) -> tuple[list[str], list[str]]:
    """The arms' layout through the IRB 14000's kinematics (``drivers/yumi/
    layout_check.py``): each arm's table box corners reachable with the pusher down, its
    rest pose above its task's ``tb_zone_z``, out of the camera's view and clear of the
    other arm, and the two arms' sweeps apart; from the calibration keys the host sends
    (``layout``), the zones and the tool frame (``tool_pusher``) the controller
    reports, and the camera's frame size: the robot moves with the controller's tool, so
    the layout is judged with it (the calibration's differing is its own FAULT)."""
    from drivers.yumi.layout_check import check_layout, layout_of
    from drivers.yumi.reach import side_of

    size = (info.get("camera") or {}).get("size")
    arms, faults = [], []
    for arm, cal in (info.get("layout") or {}).items():
        task = cal.get("task")
        ours = (rep.get("rapid") or {}).get(task) or {}
        tool = ours.get("tool")
        lay = layout_of(arm, cal, task=task, frame_size=size, zones=ours.get("zones"),
                        tool_z_mm=None if tool is None else float(tool["trans"][2]))
        if lay is not None:
            arms.append(lay)
        elif side_of(arm, task) is not None and "table_box_mm" in cal:
            faults.append(f"arm {arm}: neither the calibration (tool_z_mm) nor the "
                          f"controller (tool_pusher) gives the pusher's length: the layout "
                          f"is not checked (robot/README.md, 'The tool frame')")
    lines, bad = check_layout(arms) if arms else ([], [])
    return lines, faults + bad


def report_lines(name: str, rep: dict[str, Any], version: int,
                 tool_z: Mapping[str, float] | None = None,
                 max_speed: Mapping[str, float] | None = None) -> list[str]:
    """The controller's report as ``testbed check`` prints it (never a credential), with
    each task's ``tool_pusher`` beside the calibration's ``tool_z_mm`` (``tool_z``) and
    its TCP speed cap ``tb_v_tcp_max`` beside the calibration's ``max_speed_mm_s``
    (``max_speed``)."""
    st = rep.get("state", {})
    ratio = st.get("speedratio")
    lines = [f"      {name}: controller {rep.get('system')} serial {rep.get('serial')}, "
             f"RobotWare {rep.get('robotware')}; mode {st.get('opmode')}, "
             f"{st.get('ctrlstate')}, RAPID {st.get('execstate')}, speed ratio "
             f"{'?' if ratio is None else f'{ratio:g}'} %",
             f"      {name}: options: {', '.join(rep.get('options', [])) or 'none'}",
             f"      {name}: tasks: " + ", ".join(
                 f"{t} ({'active' if d.get('active') else 'inactive'}, {d.get('excstate')})"
                 for t, d in rep.get("tasks", {}).items())]
    for task, ours in rep.get("rapid", {}).items():
        z = ours.get("zones", {})
        lo, hi = z.get("tb_zone_lo") or ["?", "?"], z.get("tb_zone_hi") or ["?", "?"]
        v = ours.get("version")
        lines.append(f"      {name}: {task}: testbed RAPID "
                     f"{'not loaded' if v is None else f'version {v}'} (this checkout: "
                     f"{version}); world zone box x {lo[0]}..{hi[0]}, y {lo[1]}..{hi[1]} mm "
                     f"below z {z.get('tb_zone_z')}, floor z {z.get('tb_floor_z')}")
        lines.append(f"      {name}: {task}: {_tool_text(ours.get('tool'))}; the "
                     f"calibration's tool_z_mm {(tool_z or {}).get(task, '?')}")
        cap = ours.get("v_tcp_max")
        lines.append(f"      {name}: {task}: TCP speed cap tb_v_tcp_max "
                     f"{'not readable' if cap is None else f'{cap:g} mm/s'}; the "
                     f"calibration's max_speed_mm_s {(max_speed or {}).get(task, '?')}")
    return lines


def _tool_text(tool: Mapping[str, Any] | None) -> str:
    if tool is None:
        return "tool_pusher not readable"
    t, r = tool["trans"], tool["rot"]
    return (f"tool_pusher tframe [[{t[0]:g},{t[1]:g},{t[2]:g}],[{r[0]:g},{r[1]:g},{r[2]:g},"
            f"{r[3]:g}]], load {tool.get('mass', 0):g} kg (the controller's)")


def camera_lines(name: str, cam: dict[str, Any]) -> list[str]:
    """The camera as read back (``drivers/yumi/picture_quality.camera_report``): its node
    and settings, a WARN line per setting the device did not take, and each arm's crop's
    sharpness (variance of the Laplacian) and exposure (mean luma, clipped share)."""
    if not cam:
        return []
    d = cam.get("camera", {})
    got = d.get("settings") or {}
    settings = ", ".join(f"{k} {v}" for k, v in got.items() if v is not None) or "as opened"
    where = d.get("node") or d.get("source", "?")
    lines = [f"      {name}: camera {where} ({d.get('card') or d.get('kind', '?')}), "
             f"{cam.get('size', ['?', '?'])[0]}x{cam.get('size', ['?', '?'])[1]}: "
             f"{settings}"]
    lines += [f"WARN  {name}: camera setting {k} not taken: {why}"
              for k, why in (d.get("refused") or {}).items()]
    for arm, q in (cam.get("crops") or {}).items():
        if "error" in q:
            lines.append(f"WARN  {name}/{arm}: {q['error']}")
            continue
        lines.append(f"      {name}/{arm}: sharpness {q['sharpness']:.0f}, luma mean "
                     f"{q['luma_mean']:.0f} (p5 {q['luma_p5']:.0f}, p95 {q['luma_p95']:.0f}), "
                     f"clipped {100 * q['clipped']:.1f} %")
    return lines
