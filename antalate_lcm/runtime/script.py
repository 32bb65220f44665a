"""The experiment script of ``antalate run``: what the scripted operator does, as a small TOML file.

::

    mission_time = 60.0       # s the whole swarm stays in MISSION before RTL (required)
    altitude = 0.0            # take-off altitude, m above home; 0 = the HLC's default
    timeout = 180.0           # s allowed for take-off and the return together, beyond mission_time

    [[direction]]             # optional, any number, in order of `at`
    at = 10.0                 # s after the whole swarm entered MISSION
    azimuth = 45.0            # deg, 0 = north, clockwise
    speed = 1.0               # m/s
    active = true             # false = stop steering from `at` on

    [analyze]                 # optional: the metrics printed at the end (antalate analyze's options)
    radius_below = 5.0        # m: report when the swarm radius first falls below
    radius_above = 30.0       # m: ... first rises above
    range = 10.0              # m: range of the proximity graph (connectivity)

Values are strict as in every antalate config (``"60"`` is not a number); an unknown key, a
negative time or a non-finite number stops ``antalate run`` before anything flies, with one line
naming the file and the key. The same file without a path: :data:`DEFAULT_SCRIPT`.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from antalate_lcm.config import read_toml_file
from antalate_lcm.errors import ConfigError
from antalate_lcm.strict import StrictError, validate_strict


class DirectionStep(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    at: float = Field(ge=0, allow_inf_nan=False)
    azimuth: float = Field(ge=-360, le=360, allow_inf_nan=False)
    speed: float = Field(default=1.0, ge=0, allow_inf_nan=False)
    active: bool = True


class AnalyzeOptions(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)

    radius_below: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    radius_above: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    range_m: float = Field(default=10.0, gt=0, allow_inf_nan=False, alias="range")


class Script(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    mission_time: float = Field(gt=0, allow_inf_nan=False)
    altitude: float = Field(default=0.0, ge=0, le=500, allow_inf_nan=False)
    timeout: float = Field(default=180.0, gt=0, allow_inf_nan=False)
    direction: tuple[DirectionStep, ...] = ()
    analyze: AnalyzeOptions = AnalyzeOptions()


#: The script when none is given: a 30 s mission, no direction, RTL.
DEFAULT_SCRIPT = Script(mission_time=30.0)


def parse_script(table: dict[str, object], source: str) -> Script:
    """The validated script, or a :class:`ConfigError` naming ``source`` and the key."""
    try:
        script = validate_strict(Script, table)
    except StrictError as exc:
        raise ConfigError(source, exc.key, exc.message) from None
    times = [d.at for d in script.direction]
    if times != sorted(times):
        i = next(i for i in range(1, len(times)) if times[i] < times[i - 1])
        raise ConfigError(
            source, f"direction[{i}].at", f"times in order (got {times[i]:g} after {times[i - 1]:g})"
        )
    late = next((i for i, d in enumerate(script.direction) if d.at >= script.mission_time), None)
    if late is not None:
        raise ConfigError(
            source,
            f"direction[{late}].at",
            f"a time within the mission, below mission_time = {script.mission_time:g} "
            f"(got {script.direction[late].at:g})",
        )
    return script


def load_script(path: str | Path | None) -> Script:
    """Read and validate a script file; None gives :data:`DEFAULT_SCRIPT`."""
    if path is None:
        return DEFAULT_SCRIPT
    p = Path(path)
    return parse_script(read_toml_file(p), str(p))
