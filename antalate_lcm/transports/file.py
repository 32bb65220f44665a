"""The ``file://`` transport: liblcm reads (replays) or writes an LCM log as if it were a live bus.

Any antalate node, the console included, replays a log through it (docs/logging.md); nothing from
another host can arrive on it.
"""

from __future__ import annotations

import math
from typing import ClassVar

from antalate_lcm.transports.base import LcmUrl, OptionCheck, Transport, int_option


def _speed(value: str) -> str | None:
    try:
        if math.isfinite(float(value)) and value.strip() == value:
            return None
    except ValueError:
        pass
    return f"a number for option speed (replay factor; <= 0 = as fast as possible), not {value!r}"


def _mode(value: str) -> str | None:
    return (
        None
        if value in ("r", "w", "a")
        else f"r (read), w (write) or a (append) for option mode, not {value!r}"
    )


class File(Transport):
    """liblcm's ``lcm_file.c``: ``mode`` r (replay), w or a (record), ``speed`` of a replay."""

    scheme = "file"
    options: ClassVar[dict[str, OptionCheck]] = {
        "mode": _mode,
        "speed": _speed,
        "start_timestamp": int_option("start_timestamp", 0, 2**63 - 1, "microseconds since 1970, >= 0"),
    }
    network_reachable = False
    crosses_processes = False

    @classmethod
    def check(cls, u: LcmUrl) -> LcmUrl:
        if not u.network:
            raise ValueError(
                "the path of an LCM log after file:// (file:///abs/path.lcm or file://rel/path.lcm)"
            )
        return u
