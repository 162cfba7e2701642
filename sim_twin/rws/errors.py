"""What the RWS twin answers when a request is refused, and where each code comes from.

Why one table: every refusal the twin makes (start in manual mode, motors off, an unknown
symbol, ...) is a promise about what a real IRC5 answers, and a lab checks each one on
day one (docs/rws-checklist.md). Keeping the codes here, each with its source, makes that
check a matter of reading one file.

Codes are RobotWare return codes (negative 32-bit, as RWS prints them). Sources:

- ``GENERIC`` (-1073414146, 0xC004FFFE): the manual's own example of a refused request
  (3HAC050973-001, "RobotWare return codes service": a RAPID variable set without
  mastership answers HTTP 400 with this code; its ``msg`` names the controller's own code,
  0xC004841D). The twin uses it, with the specific code in ``msg``, for refusals whose
  real code nobody here has seen.
- ``MASTER_REJECT`` (0xC004841D): the ``new_code`` of that same example.
- ``EXEC_STATE`` (0xC0049007): the error code the manual's "Get RAPID task state" example
  links; its name (SYS_CTRL_E_EXEC_STATE) as client code for RW6 spells it.
- ``NO_SUCH_SYMBOL`` (0xC0049000), ``MODE_REJECT`` (0xC004841C): names and values as RW6
  client code spells them; not seen in the manual. Unverified.
"""

from __future__ import annotations

from dataclasses import dataclass

GENERIC = -1073414146
MASTER_REJECT = -1073445859
EXEC_STATE = -1073442809
NO_SUCH_SYMBOL = -1073442816
MODE_REJECT = -1073445860

NAMES = {GENERIC: "SYS_CTRL_E_GENERIC (as the manual's example)",
         MASTER_REJECT: "SYS_CTRL_E_MASTER_REJECT", EXEC_STATE: "SYS_CTRL_E_EXEC_STATE",
         NO_SUCH_SYMBOL: "SYS_CTRL_E_NO_SUCH_SYMBOL", MODE_REJECT: "SYS_CTRL_E_MODE_REJECT"}


@dataclass(eq=False)
class RwsError(Exception):
    """A refused request: the HTTP status, the RobotWare code and a message, as RWS puts
    them in its ``status`` element."""

    status: int
    code: int
    msg: str

    def __str__(self) -> str:
        return f"HTTP {self.status} code {self.code}: {self.msg}"


def refused(status: int, code: int, why: str) -> RwsError:
    """An error whose ``msg`` reads like RWS's: where, what, and the controller code."""
    name = NAMES.get(code, "")
    return RwsError(status, code, f"rws twin: {why} (code {code & 0xFFFFFFFF:#010x} {name})")
