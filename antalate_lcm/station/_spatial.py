"""In-memory spatial index over the agents' latest positions: a uniform latitude/longitude grid.

Why a grid: the station answers one query per report, always with the same radius (the sensing
range), and positions move a little at every report. A grid sized to that radius makes both an
update and a query O(1) plus the number of peers actually nearby, with no rebalancing; a tree
would buy nothing here. Cells are square in *degrees*, with a side a little under the range in
metres of latitude, so a query reads a 3×3 block of cells at the equator and a few more columns
towards the poles (where a degree of longitude is shorter). The number of columns divides 360
exactly, so the block wraps cleanly across the antimeridian; a query reaching a pole reads its
whole rows.

The index only proposes *candidates*: every peer within range is among them (bounds below are
conservative), and the exact geodesic test in `sector` decides.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterator

#: WGS84 semi-major axis (m): a lower bound for the radius of any parallel per cos(latitude).
_A = 6378137.0
#: Metres per degree of latitude at the equator, the smallest anywhere on WGS84.
_MIN_M_PER_DEG_LAT = 110_574.0
_SAFETY = 1.001


class GridIndex:
    """Positions by key (an agent's token), with a last-report time for staleness filtering."""

    __slots__ = ("_cell_deg", "_ncols", "_range_m", "_rows", "_entries")

    def __init__(self, range_m: float) -> None:
        if not range_m > 0.0:
            raise ValueError(f"range_m must be > 0, not {range_m}")
        self._range_m = range_m
        wanted = range_m / _MIN_M_PER_DEG_LAT
        self._ncols = max(1, math.ceil(360.0 / wanted))
        self._cell_deg = 360.0 / self._ncols
        # row -> col -> key -> [lat, lon, t]
        self._rows: dict[int, dict[int, dict[Hashable, list[float]]]] = {}
        self._entries: dict[Hashable, tuple[int, int, list[float]]] = {}

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def _cell(self, lat: float, lon: float) -> tuple[int, int]:
        row = math.floor((lat + 90.0) / self._cell_deg)
        col = math.floor((lon + 180.0) / self._cell_deg) % self._ncols
        return row, col

    def update(self, key: Hashable, lat: float, lon: float, t: float) -> None:
        """Place or move ``key``; cheap when it stays in its cell (the common case at 10 Hz)."""
        row, col = self._cell(lat, lon)
        old = self._entries.get(key)
        if old is not None:
            old_row, old_col, entry = old
            if old_row == row and old_col == col:
                entry[0], entry[1], entry[2] = lat, lon, t
                return
            self._drop(key, old_row, old_col)
        entry = [lat, lon, t]
        self._rows.setdefault(row, {}).setdefault(col, {})[key] = entry
        self._entries[key] = (row, col, entry)

    def remove(self, key: Hashable) -> None:
        old = self._entries.pop(key, None)
        if old is not None:
            self._drop(key, old[0], old[1])

    def _drop(self, key: Hashable, row: int, col: int) -> None:
        cols = self._rows[row]
        cell = cols[col]
        del cell[key]
        if not cell:
            del cols[col]
            if not cols:
                del self._rows[row]

    def sweep(self, older_than: float) -> int:
        """Forget entries last updated before ``older_than``; keeps queries proportional to live agents."""
        dead = [key for key, (_, _, entry) in self._entries.items() if entry[2] < older_than]
        for key in dead:
            self.remove(key)
        return len(dead)

    def candidates(
        self, lat: float, lon: float, *, since: float = -math.inf, exclude: Hashable = None
    ) -> Iterator[tuple[float, float]]:
        """(lat, lon) of every entry that may lie within the range of (lat, lon).

        Entries last updated before ``since`` (stale agents) and the entry ``exclude`` (the reporter
        itself) are skipped.
        """
        cd = self._cell_deg
        ext_lat = self._range_m / _MIN_M_PER_DEG_LAT * _SAFETY
        r0 = math.floor((max(-90.0, lat - ext_lat) + 90.0) / cd)
        r1 = math.floor((min(90.0, lat + ext_lat) + 90.0) / cd)
        polemost = min(90.0, abs(lat) + ext_lat)
        cos_pole = math.cos(math.radians(polemost))
        ext_lon = math.inf if cos_pole < 1e-9 else math.degrees(self._range_m * _SAFETY / (_A * cos_pole))
        ncols = self._ncols
        whole_rows = ext_lon >= 180.0
        c0 = c1 = 0
        if not whole_rows:
            c0 = math.floor((lon - ext_lon + 180.0) / cd)
            c1 = math.floor((lon + ext_lon + 180.0) / cd)
            if c1 - c0 + 1 >= ncols:
                whole_rows = True
        rows = self._rows
        for row in range(r0, r1 + 1):
            cols = rows.get(row)
            if cols is None:
                continue
            cells = cols.values() if whole_rows else (cols.get(c % ncols) for c in range(c0, c1 + 1))
            for cell in cells:
                if cell is None:
                    continue
                for key, entry in cell.items():
                    if entry[2] >= since and key != exclude:
                        yield entry[0], entry[1]
