"""Robot Web Services 1.0 for the YuMi hardware twin: the controller's own API.

Why it exists: on day one the agent drives the YuMi through the unchanged ABB clients
(``abb_robot_client.rws``, ``abb_motion_program_exec``) over RWS, as against a real IRC5
with RobotWare 6. The hardware twin once spoke a private JSON API instead, so that path
was never exercised before the robot; ``sim_twin.yumi_server`` now serves this package
beside its camera and nothing else. This package is an RWS 1.0 endpoint the clients run
against unchanged: digest authentication and RobotWare's sessions (and their limit), the
resources and answers the clients parse, and a controller whose states (manual mode,
motors off, guard stop, a program running, a RAPID error) answer as a real one does.
Every answer it assumes is a line of docs/rws-checklist.md; docs/notes/rws.md says what
it covers.

Parts: ``irc5`` (the controller model and the start-hook seam), ``resources`` (the
routes), ``rws_service`` (auth, sessions, the lab side channel), ``rws_server`` (HTTP),
``digest_auth``, ``event_log``, ``file_store``, ``io_signals``, ``rapid_data``,
``mechunits``, ``cell_link`` (positions from a ``YumiTwinCell``), ``shapes`` (JSON and
XHTML), ``motion_program`` (the library's program file, decoded) and ``motion_exec``
(``CellMotion``: the start hook that runs those programs on a ``YumiTwinCell``, as the
library's own RAPID would), ``testbed_rapid`` (``TestbedRapid``: the same with the
semantics of the project's RAPID, ``robot/rapid/``: one program file per task, and its
stationary world zones), ``world_zones`` (those zones as boxes), ``testbed_install``
(our modules' symbols in the tasks, loadable and unloadable), ``request_log`` (one JSON
line per request served) and ``login_file`` (an extra login from an owner-only file).
``python -m sim_twin.rws`` serves one (``--cell``: with the twin's pushers moving, our
RAPID's semantics or, with ``--rapid library``, the library's).

Use::

    from sim_twin.rws import Irc5Controller, serve
    server = serve(Irc5Controller(on_start=my_hook), max_sessions=3)
    # RWS(server.url) ... ; server.stop()
"""

from __future__ import annotations

from collections.abc import Mapping

from sim_twin.rws.irc5 import Identity, Irc5Controller, ProgramRun, RapidError, StartHook
from sim_twin.rws.mechunits import YUMI_UNITS, MechUnit, StaticPoses
from sim_twin.rws.rws_server import RwsServer
from sim_twin.rws.rws_service import RwsService


def serve(controller: Irc5Controller | None = None, *, host: str = "127.0.0.1",
          port: int = 0, users: Mapping[str, str] | None = None, max_sessions: int = 70,
          idle_timeout_s: float | None = None, verbose: bool = False) -> RwsServer:
    """An RWS twin serving ``controller`` (a default YuMi if None) in a daemon thread."""
    service = RwsService(controller or Irc5Controller(), users=users,
                         max_sessions=max_sessions, idle_timeout_s=idle_timeout_s)
    return RwsServer(service, host, port, verbose=verbose).start_thread()


__all__ = ["YUMI_UNITS", "Identity", "Irc5Controller", "MechUnit", "ProgramRun",
           "RapidError", "RwsServer", "RwsService", "StartHook", "StaticPoses", "serve"]
