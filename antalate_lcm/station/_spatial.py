"""In-memory spatial index over the agents' latest positions: a uniform latitude/longitude grid.

Why a grid: the station asks one question per report, always about a region of the same size
(the box around the reporter's front sector), and positions move a little at every report. A grid
makes both an update and a query O(1) plus the number of agents actually nearby, with no
rebalancing; a tree would buy nothing here. Cells are square in *degrees*, half the sensing range
on a side in metres of latitude, so a sector's box covers a handful of cells (a few more columns
towards the poles, where a degree of longitude is shorter). The number of columns divides 360
exactly, so a box wraps cleanly across the antimeridian.

The index only proposes *candidates*; `sector.detect` decides. It is used from one thread.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterator

#: Metres per degree of latitude at the equator, the smallest anywhere on WGS84.
_MIN_M_PER_DEG_LAT = 110_574.0


class GridIndex:
    """Positions by key (an agent's token), each with its last-report time for staleness filtering."""

    __slots__ = ("_cell_deg", "_ncols", "_rows", "_entries")

    def __init__(self, cell_m: float) -> None:
        if not cell_m > 0.0:
            raise ValueError(f"cell_m must be > 0, not {cell_m}")
        self._ncols = max(1, math.ceil(360.0 / (cell_m / _MIN_M_PER_DEG_LAT)))
        self._cell_deg = 360.0 / self._ncols
        # row -> col -> key -> [lat, lon, t]; empty cells and rows are deleted, so a scan of a
        # whole row only visits occupied cells.
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
        """Forget entries last updated before ``older_than``: queries then cost what the live agents cost."""
        dead = [key for key, (_, _, entry) in self._entries.items() if entry[2] < older_than]
        for key in dead:
            self.remove(key)
        return len(dead)

    def candidates(
        self,
        south: float,
        north: float,
        west: float,
        east: float,
        *,
        since: float = -math.inf,
        exclude: Hashable = None,
    ) -> Iterator[tuple[float, float]]:
        """(lat, lon) of every entry whose cell meets the box (a superset of the entries inside it).

        ``west > east`` means the box crosses the antimeridian. Entries last updated before
        ``since`` (stale agents) and the entry ``exclude`` (the reporter itself) are skipped.
        """
        cd = self._cell_deg
        ncols = self._ncols
        r0 = math.floor((south + 90.0) / cd)
        r1 = math.floor((north + 90.0) / cd)
        c0 = math.floor((west + 180.0) / cd)
        c1 = math.floor((east + (180.0 if west <= east else 540.0)) / cd)
        whole_rows = c1 - c0 + 1 >= ncols
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
