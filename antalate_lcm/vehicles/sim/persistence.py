"""`StateFile`: a sim vehicle outlives the software that flies it, as a real one does.

With ``state_file`` set, the adapter writes the vehicle's state there while connected and reads it
back on `connect`, so that a restarted HLC process finds the vehicle where it was -- in the air,
armed, at its altitude -- and flown on for the time it was gone.
"""

from __future__ import annotations

import json
import os
import time

from antalate_lcm.vehicles.sim.physics import PERSISTED, Motion, Quadcopter

__all__ = ["StateFile"]

#: Wall-clock seconds between two writes (the HLC polls 20 times a second).
_EVERY = 0.2
#: An older file is a vehicle long landed or another run's: start on the ground instead.
_FRESH_FOR = 60.0


class StateFile:
    """One vehicle's state file: written atomically (a crash mid-write leaves the previous one)."""

    __slots__ = ("_path", "_saved_at")

    def __init__(self, path: str) -> None:
        self._path = path
        self._saved_at = 0.0

    def save(self, vehicle: Quadcopter) -> None:
        """Write `vehicle`'s state, unless written less than `_EVERY` s ago."""
        wall = time.time()
        if wall - self._saved_at < _EVERY:
            return
        self._saved_at = wall
        data = {k: getattr(vehicle, k) for k in PERSISTED}
        data["phase"] = vehicle._phase.name
        data["saved_at"] = wall
        tmp = f"{self._path}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(data, f)
        os.replace(tmp, self._path)

    def restore(self, vehicle: Quadcopter) -> None:
        """Put `vehicle` back where the file left it; nothing if there is no fresh, readable file."""
        try:
            with open(self._path, encoding="utf-8") as f:
                data = json.load(f)
        except (OSError, ValueError):
            return  # none, or unreadable: start on the ground, as a vehicle that was never flown
        gap = time.time() - float(data.get("saved_at", 0.0))
        if not 0.0 <= gap <= _FRESH_FOR:
            return
        for k in PERSISTED:
            if k in data:
                setattr(vehicle, k, data[k])
        vehicle._phase = Motion[data.get("phase", "GROUND")]
        if vehicle.in_air:
            vehicle._airborne_since = vehicle._sim_time
        # The vehicle flew on while nobody was listening.
        vehicle._t_last = vehicle.clock() - gap / vehicle._time_scale
