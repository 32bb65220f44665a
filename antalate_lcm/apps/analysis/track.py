"""One agent's trajectory in the local frame, and where it was at any instant (pure)."""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Track:
    """One agent's positions (metres north/east of the frame origin, altitude above home) and its
    reported velocity (m/s north/east, from ``telemetry_t.vn``/``ve``), sorted by time."""

    t: list[float]
    north: list[float]
    east: list[float]
    alt: list[float]
    vn: list[float] = field(default_factory=list)
    ve: list[float] = field(default_factory=list)

    def _around(self, t: float, max_age: float) -> tuple[int, float] | None:
        """(index of the sample at or before ``t``, interpolation fraction towards the next one)."""
        i = bisect.bisect_right(self.t, t)
        if i == 0:
            return None
        t0 = self.t[i - 1]
        if i < len(self.t) and self.t[i] - t0 <= max_age and self.t[i] > t0:
            return i - 1, (t - t0) / (self.t[i] - t0)
        if t - t0 > max_age:
            return None
        return i - 1, 0.0

    def _interpolated(
        self, xs: list[float], ys: list[float], t: float, max_age: float
    ) -> tuple[float, float] | None:
        at = self._around(t, max_age)
        if at is None:
            return None
        i, f = at
        if f == 0.0:
            return xs[i], ys[i]
        return xs[i] + f * (xs[i + 1] - xs[i]), ys[i] + f * (ys[i + 1] - ys[i])

    def position_at(self, t: float, max_age: float) -> tuple[float, float] | None:
        """(north, east) at ``t``, interpolated between the samples around it; None when silent.

        Interpolation needs both neighbours within ``max_age`` of each other; otherwise the latest
        sample counts if it is at most ``max_age`` old.
        """
        return self._interpolated(self.north, self.east, t, max_age)

    def velocity_at(self, t: float, max_age: float) -> tuple[float, float] | None:
        """(vn, ve) last reported at or before ``t`` (at most ``max_age`` old); None when silent or
        when the track carries no velocities.

        Held, not interpolated: a velocity can step between two reports (the simulator's RTL sets
        5 m/s home at once), and interpolating across the step invents a velocity nobody flew. At
        the end of a mission, which is the instant of the first RTL, it made a flock flying at
        polarisation 0.9996 read 0.26.
        """
        if not self.vn:
            return None
        i = bisect.bisect_right(self.t, t)
        if i == 0 or t - self.t[i - 1] > max_age:
            return None
        return self.vn[i - 1], self.ve[i - 1]
