"""A point of a sweep's grid, or a protocol's way: config fields set on a fleet.

Why its own module: a sweep (``sweep.py``) runs every point of its grid, and a protocol
(``protocol.py``) runs its ways (``[ways.<name>] set = {...}``) the same way; both
apply fields to a fleet config and validate the result as a config file would be, and
neither should import the other for it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from testbed.core.config import ConfigError
from testbed.experiments.fleet_config import FleetConfig, parse_config

__all__ = ["ALGORITHM_KEY", "SweepPoint"]

ALGORITHM_KEY = "algorithm"
"""The grid key that varies the algorithm (an ablation study) instead of a field."""


@dataclass(frozen=True)
class SweepPoint:
    values: dict[str, Any]

    @property
    def label(self) -> str:
        """``humans.count-2`` (keys joined by ``_``): the report's line and the run's name."""
        text = "_".join(f"{k}-{v}" for k, v in self.values.items())
        return re.sub(r"[^A-Za-z0-9_.+-]", "", text)

    def algorithm(self, default: str) -> str:
        return str(self.values.get(ALGORITHM_KEY, default))

    def apply(self, fleet: FleetConfig) -> FleetConfig:
        """``fleet`` with this point's fields set, validated as a config file would be."""
        data = fleet.model_dump(mode="json", exclude_none=True)
        for key, value in self.values.items():
            if key == ALGORITHM_KEY:
                continue
            *path, last = key.split(".")
            node = data
            for part in path:
                if not isinstance(node.get(part), dict):
                    raise ConfigError(f"grid.{key}: no such config field (fleet.{key})")
                node = node[part]
            if last not in node and last not in _fields_at(path):
                raise ConfigError(f"grid.{key}: no such config field (fleet.{key})")
            node[last] = value
        return parse_config(data, f"grid point {self.label}", check_files=False,
                            prefix=("fleet",))


def _fields_at(path: list[str]) -> set[str]:
    """The field names of the config section at ``path`` (optional ones unset too)."""
    model: Any = FleetConfig
    for part in path:
        info = model.model_fields.get(part)
        if info is None or not isinstance(info.annotation, type):
            return set()
        model = info.annotation
    return set(getattr(model, "model_fields", {}))
