"""The driver's error taxonomy: names that say what went wrong on the way to a robot.

Why a taxonomy (as Gymnasium's ``error.py``): the fleet decides per error *kind* what
to do with a host. A :class:`ProtocolError` or :class:`LinkClosed` means the byte stream
can no longer be trusted, so the link is dropped and rebuilt; a :class:`DeadlineExceeded`
means the peer may be dead (paramiko's keepalive never notices), so the same; an
:class:`AgentError` is a clean refusal from a healthy agent (a backend exception with its
remote traceback), so the link stays up. Every one of them ends as a
``testbed.core.types.Fault`` for the host's arms, never as a hang or a crash of the
controller.
"""

from __future__ import annotations


class DriverError(Exception):
    """Base of everything the drivers raise about a host or its agent."""


class ProtocolError(DriverError):
    """A frame or message that breaks the wire protocol (either direction)."""


class TruncatedFrame(ProtocolError):
    """The stream ended inside a frame (the peer died or closed mid-write)."""


class LinkClosed(DriverError):
    """The peer closed the byte stream (agent exited, channel or connection gone)."""


class DeadlineExceeded(DriverError):
    """A call did not complete within its deadline; the peer may be dead or stuck."""


class HostKeyError(DriverError):
    """The SSH server's host key is unknown or differs from the known_hosts entry."""


class TransportError(DriverError):
    """The transport could not be opened (connect, auth, exec, spawn)."""


class AgentError(DriverError):
    """A healthy agent reported an error for one request (e.g. a backend exception).

    ``arm`` names the arm whose operation raised, when the agent knows it;
    ``remote_traceback`` is the agent-side traceback text.
    """

    def __init__(self, message: str, *, kind: str = "backend", arm: str | None = None,
                 remote_traceback: str = "", fatal: bool = False) -> None:
        super().__init__(message)
        self.kind = kind
        self.arm = arm
        self.remote_traceback = remote_traceback
        self.fatal = fatal


class BackendError(DriverError):
    """A backend could not do what was asked (camera gone, controller refused, ...)."""


class ConformanceError(AssertionError):
    """A backend does not meet the ``HostBackend`` contract (see drivers.conformance)."""
