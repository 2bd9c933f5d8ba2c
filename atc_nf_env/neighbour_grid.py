"""A uniform grid over one world's aircraft: the kernel's neighbour search in O(N).

The kernel asks three questions of the aircraft's positions at each step: which aircraft
are within the sensing radius of aircraft i (the NF's neighbours, in index order), is any
pair within it (a step with none is ordinary), and what is the smallest pairwise
separation (the trace's, over every pair however far) with the pairs below the separation
minimum. Over all pairs each costs O(N²) a step. Here the aircraft are sorted into square
cells at least as wide as the sensing radius and the separation minimum (``cell_nm``), so
that two aircraft in cells that are not adjacent are farther apart than either: the first
two questions look at the 3 × 3 cells around each aircraft only. The smallest separation
is kept exact: the cells around each aircraft are searched ring by ring, outward, until
the smallest distance found is below the distance that every pair not yet looked at is
known to exceed (one ring of adjacent cells settles it once any pair is within a cell).
Every distance is computed in the same arithmetic as the all-pairs loops, and the
neighbours come out in index order, so the NF's products and sums are taken in the same
order: the kernel flies the same bits with the grid as without (``tests/test_neighbour_grid.py``).

The grid covers the aircraft's bounding box, in at most 2 N cells (wider cells where the
box is larger, fewer aircraft per cell being then no longer the point), so that building it
costs O(N); aircraft outside it (none, by construction, but for rounding) are clamped into
its border cells, which keeps the distance bounds. The cells are a skin wider than needed,
and a grid serves until an aircraft has moved half a skin since it was built (``prepare``):
a step's sub-steps share one. Its scratch (``grid_rows`` rows of N, ``KernelScratch.cells``)
holds positions, a membership flag, each aircraft's cell, the aircraft sorted by cell (a
stable counting sort), one aircraft's neighbour list, and one row per row of cells holding
where each cell's aircraft start in the sorted list (indices stored as float64, exact below
2^53). Nothing is allocated.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from atc_nf_env.nf import FAST_MATH_FLAGS, NO_REFERENCE_COUNTS
from atc_nf_env import compile_cache

# Before any @njit: numba picks a function's cache locator when its decorator runs.
compile_cache.install()

# Rows of the grid's scratch, from its first row.
GRID_X = 0  # position x of each aircraft now, nm (filled by the caller)
GRID_Y = 1  # position y, nm
GRID_MEMBER = 2  # 1 where the aircraft is asked about now (filled by the caller), else 0
GRID_X0 = 3  # position x when the grid was built, nm
GRID_Y0 = 4  # position y
GRID_CX = 5  # its cell's column
GRID_CY = 6  # its cell's row
GRID_ITEM = 7  # the members sorted by cell, in index order within a cell
GRID_LIST = 8  # one aircraft's neighbours (``neighbours``)
GRID_META = 9  # column 0 of rows GRID_META ... + 3: built (1) or not (0), nx, ny, cell width nm
GRID_TABLE = 13  # row GRID_TABLE + cy: column cx the start of cell (cx, cy) in GRID_ITEM, column nx its row's end

#: Relative widening of the cells beyond ``cell_nm``, and (times the largest coordinate) the
#: absolute one: far beyond the rounding of any distance or cell index, so that aircraft in
#: cells that are not adjacent are farther apart than ``cell_nm`` in any arithmetic.
_WIDEN_REL = 1.0e-6
_WIDEN_ABS = 1.0e-9
#: Margin of the bound that pairs not yet looked at exceed (r cells: r · width · (1 − margin)).
_BOUND_MARGIN = 1.0e-5
#: Skin of the cells, as a fraction of ``cell_nm``: the cells are this much wider, and a grid
#: serves (``prepare``) until an aircraft has moved half of it along x or y since it was built.
SKIN = 0.25


def cell_rows(n_aircraft: int) -> int:
    """Rows of cells the grid may have for ``n_aircraft`` (its columns: at most N − 1)."""
    return int(math.ceil(2.0 * math.sqrt(max(n_aircraft, 1)))) + 1


def grid_rows(n_aircraft: int) -> int:
    """Rows of scratch (each of ``n_aircraft`` columns) the grid needs."""
    return GRID_TABLE + cell_rows(n_aircraft)


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def build(g: np.ndarray, base: int, n: int, cell_nm: float) -> tuple[float, float, float, int, int]:
    """Sort the members (``g[base + GRID_MEMBER, i] != 0``, at ``GRID_X``/``GRID_Y``) of the
    first ``n`` columns into cells at least ``cell_nm`` (the skin included) wide. Returns (x
    and y of the grid's corner nm, cell width nm, columns nx, rows ny); nx = 0 when fewer
    than two are members."""
    x_lo = math.inf
    x_hi = -math.inf
    y_lo = math.inf
    y_hi = -math.inf
    members = 0
    for i in range(n):
        if g[base + GRID_MEMBER, i] != 0.0:
            x = g[base + GRID_X, i]
            y = g[base + GRID_Y, i]
            x_lo = min(x_lo, x)
            x_hi = max(x_hi, x)
            y_lo = min(y_lo, y)
            y_hi = max(y_hi, y)
            members += 1
    for i in range(n):
        g[base + GRID_X0, i] = g[base + GRID_X, i]
        g[base + GRID_Y0, i] = g[base + GRID_Y, i]
        g[base + GRID_CX, i] = -1.0  # not a member
    if members < 2:
        g[base + GRID_META, 0] = 1.0
        g[base + GRID_META + 1, 0] = 0.0
        g[base + GRID_META + 2, 0] = 0.0
        g[base + GRID_META + 3, 0] = 1.0
        return 0.0, 0.0, 1.0, 0, 0
    largest = max(max(abs(x_lo), abs(x_hi)), max(abs(y_lo), abs(y_hi)))
    width = cell_nm * (1.0 + _WIDEN_REL) + _WIDEN_ABS * largest
    tables = g.shape[0] - base - GRID_TABLE
    span_x = x_hi - x_lo
    span_y = y_hi - y_lo
    fx = span_x / width
    fy = span_y / width
    # Wider cells until the box fits: at most N − 1 columns (one more holds each row's
    # end), the rows there are, and 2 N cells. Bounded, whatever the coordinates.
    for _ in range(4000):
        if fx < n - 1 and fy < tables and (fx + 1.0) * (fy + 1.0) <= 2.0 * n:
            break
        width *= 1.5
        fx = span_x / width
        fy = span_y / width
    nx = min(max(int(fx) + 1, 1), n - 1)
    ny = min(max(int(fy) + 1, 1), tables)
    inv_width = 1.0 / width
    table = base + GRID_TABLE
    for cy in range(ny):
        for cx in range(nx + 1):
            g[table + cy, cx] = 0.0
    for i in range(n):
        if g[base + GRID_MEMBER, i] != 0.0:
            # Clamped as integers: a NaN coordinate gives some cell, never an index outside.
            cx = min(max(int((g[base + GRID_X, i] - x_lo) * inv_width), 0), nx - 1)
            cy = min(max(int((g[base + GRID_Y, i] - y_lo) * inv_width), 0), ny - 1)
            g[base + GRID_CX, i] = cx
            g[base + GRID_CY, i] = cy
            g[table + cy, cx] += 1.0
    # Counts to the ends of the cells in the sorted list; the members placed from the last
    # down make them the starts, in index order within each cell.
    total = 0.0
    for cy in range(ny):
        for cx in range(nx):
            total += g[table + cy, cx]
            g[table + cy, cx] = total
        g[table + cy, nx] = total
    for i in range(n - 1, -1, -1):
        if g[base + GRID_MEMBER, i] != 0.0:
            cell = table + int(g[base + GRID_CY, i])
            cx = int(g[base + GRID_CX, i])
            g[cell, cx] -= 1.0
            g[base + GRID_ITEM, int(g[cell, cx])] = i
    g[base + GRID_META, 0] = 1.0
    g[base + GRID_META + 1, 0] = nx
    g[base + GRID_META + 2, 0] = ny
    g[base + GRID_META + 3, 0] = width
    return x_lo, y_lo, width, nx, ny


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def forget(g: np.ndarray, base: int) -> None:
    """No grid built: the next ``prepare`` builds one (a new call, whose aircraft may be others)."""
    g[base + GRID_META, 0] = 0.0


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def prepare(g: np.ndarray, base: int, n: int, cell_nm: float) -> tuple[int, int, float, float]:
    """A grid for the members and positions the caller filled in (``GRID_MEMBER``,
    ``GRID_X``, ``GRID_Y`` of the first ``n`` columns): the one built before if every member
    now was one then and has moved at most half a skin along x and y since, else a new one
    with cells ``cell_nm`` plus a skin wide. Returns (nx, ny, cell width nm, skin nm) for
    the queries. Within one kernel call aircraft only ever stop being members, so the
    caller ``forget``s the grid when a call begins."""
    skin = SKIN * cell_nm
    if g[base + GRID_META, 0] != 0.0:
        half = 0.5 * skin
        still = True
        for i in range(n):
            if g[base + GRID_MEMBER, i] != 0.0:
                # A NaN fails both tests and rebuilds.
                still &= (g[base + GRID_CX, i] >= 0.0) & (abs(g[base + GRID_X, i] - g[base + GRID_X0, i]) <= half) & (
                    abs(g[base + GRID_Y, i] - g[base + GRID_Y0, i]) <= half)
        if still:
            return int(g[base + GRID_META + 1, 0]), int(g[base + GRID_META + 2, 0]), g[base + GRID_META + 3, 0], skin
    _, _, width, nx, ny = build(g, base, n, cell_nm + skin)
    return nx, ny, width, skin


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def any_within(g: np.ndarray, base: int, n: int, nx: int, ny: int, radius2: float, inv_len: float) -> bool:
    """Whether two members are within the sensing radius, in the NF's arithmetic
    ((x_i / L − x_j / L)² + (y_i / L − y_j / L)² < ``radius2``, in units of L²)."""
    if nx == 0:
        return False
    table = base + GRID_TABLE
    for i in range(n):
        if g[base + GRID_MEMBER, i] == 0.0:
            continue
        cx = int(g[base + GRID_CX, i])
        cy = int(g[base + GRID_CY, i])
        xi = g[base + GRID_X, i] * inv_len
        yi = g[base + GRID_Y, i] * inv_len
        lo_x = max(cx - 1, 0)
        hi_x = min(cx + 2, nx)
        for yy in range(max(cy - 1, 0), min(cy + 2, ny)):
            for k in range(int(g[table + yy, lo_x]), int(g[table + yy, hi_x])):
                j = int(g[base + GRID_ITEM, k])
                if j <= i or g[base + GRID_MEMBER, j] == 0.0:
                    continue
                rx = xi - g[base + GRID_X, j] * inv_len
                ry = yi - g[base + GRID_Y, j] * inv_len
                if rx * rx + ry * ry < radius2:
                    return True
    return False


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def neighbours(g: np.ndarray, base: int, i: int, nx: int, ny: int, radius2: float, inv_len: float) -> int:
    """The members other than ``i`` within the sensing radius of member ``i``, in the NF's
    arithmetic, into ``g[base + GRID_LIST]`` in increasing index; returns their number.
    Members are those flagged in ``GRID_MEMBER`` now: flags cleared since ``build`` (a grid
    of the same positions reused for fewer aircraft) leave those aircraft out."""
    if nx == 0:
        return 0
    table = base + GRID_TABLE
    row = base + GRID_LIST
    cx = int(g[base + GRID_CX, i])
    cy = int(g[base + GRID_CY, i])
    xi = g[base + GRID_X, i] * inv_len
    yi = g[base + GRID_Y, i] * inv_len
    lo_x = max(cx - 1, 0)
    hi_x = min(cx + 2, nx)
    count = 0
    for yy in range(max(cy - 1, 0), min(cy + 2, ny)):
        for k in range(int(g[table + yy, lo_x]), int(g[table + yy, hi_x])):
            j = int(g[base + GRID_ITEM, k])
            if j == i or g[base + GRID_MEMBER, j] == 0.0:
                continue
            rx = xi - g[base + GRID_X, j] * inv_len
            ry = yi - g[base + GRID_Y, j] * inv_len
            if rx * rx + ry * ry >= radius2:
                continue
            # Insertion in index order (a few neighbours at most, in practice).
            p = count
            while p > 0 and g[row, p - 1] > j:
                g[row, p] = g[row, p - 1]
                p -= 1
            g[row, p] = j
            count += 1
    return count


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def _closest_in(g: np.ndarray, base: int, i: int, start: int, end: int, least2: float) -> float:
    """``least2`` lowered to the smallest squared distance (nm²) from member ``i`` to the
    members of index above ``i`` at ``GRID_ITEM`` positions start … end − 1."""
    xi = g[base + GRID_X, i]
    yi = g[base + GRID_Y, i]
    for k in range(start, end):
        j = int(g[base + GRID_ITEM, k])
        if j <= i or g[base + GRID_MEMBER, j] == 0.0:
            continue
        sx = xi - g[base + GRID_X, j]
        sy = yi - g[base + GRID_Y, j]
        least2 = min(least2, sx * sx + sy * sy)
    return least2


@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy", **NO_REFERENCE_COUNTS)
def separation(g: np.ndarray, base: int, n: int, nx: int, ny: int, width: float, skin: float, least2: float,
               sep_min2: float, los_pairs: np.ndarray, mark: bool) -> tuple[float, bool]:
    """The smallest squared separation (nm²) among the members, and ``least2`` if smaller
    (exact, over every pair), and whether a pair is closer than the separation minimum
    (``sep_min2`` nm², at most the cells' width squared), marked in ``los_pairs`` (both
    ways) with ``mark``. The same squared distances as the all-pairs loop, so the same
    minimum."""
    if nx == 0:
        return least2, False
    table = base + GRID_TABLE
    lost = False
    # Adjacent cells: every pair within a cell's width, the losses of separation among them.
    for i in range(n):
        if g[base + GRID_MEMBER, i] == 0.0:
            continue
        cx = int(g[base + GRID_CX, i])
        cy = int(g[base + GRID_CY, i])
        xi = g[base + GRID_X, i]
        yi = g[base + GRID_Y, i]
        lo_x = max(cx - 1, 0)
        hi_x = min(cx + 2, nx)
        for yy in range(max(cy - 1, 0), min(cy + 2, ny)):
            for k in range(int(g[table + yy, lo_x]), int(g[table + yy, hi_x])):
                j = int(g[base + GRID_ITEM, k])
                if j <= i or g[base + GRID_MEMBER, j] == 0.0:
                    continue
                sx = xi - g[base + GRID_X, j]
                sy = yi - g[base + GRID_Y, j]
                sep2 = sx * sx + sy * sy
                least2 = min(least2, sep2)
                if sep2 < sep_min2:
                    lost = True
                    if mark:
                        los_pairs[i, j] = 1
                        los_pairs[j, i] = 1
    # Rings r = 2, 3, … of cells (Chebyshev distance r) until every pair not looked at is
    # known to be farther apart than the smallest found: cells r + 1 apart were more than
    # r widths apart along x or y when the grid was built, and two aircraft have since
    # closed in by at most a skin along each (half a skin each).
    r = 1
    while r < max(nx, ny) - 1:
        bound = r * width * (1.0 - _BOUND_MARGIN) - 1.5 * skin
        if least2 < bound * bound:
            break
        r += 1
        for i in range(n):
            if g[base + GRID_MEMBER, i] == 0.0:
                continue
            cx = int(g[base + GRID_CX, i])
            cy = int(g[base + GRID_CY, i])
            for yy in range(max(cy - r, 0), min(cy + r + 1, ny)):
                if yy == cy - r or yy == cy + r:
                    lo_x = max(cx - r, 0)
                    hi_x = min(cx + r + 1, nx)
                    if lo_x < hi_x:
                        least2 = _closest_in(g, base, i, int(g[table + yy, lo_x]), int(g[table + yy, hi_x]), least2)
                else:
                    if cx - r >= 0:
                        least2 = _closest_in(g, base, i, int(g[table + yy, cx - r]), int(g[table + yy, cx - r + 1]),
                                             least2)
                    if cx + r < nx:
                        least2 = _closest_in(g, base, i, int(g[table + yy, cx + r]), int(g[table + yy, cx + r + 1]),
                                             least2)
    return least2, lost
