"""``atc-nf fly``: its airspeed figure shows the table's extremes, and its table is computed
in bounded memory with today's numbers."""

from __future__ import annotations

import re
import tracemalloc
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atc_nf_env import tables
from atc_nf_env.cli import main
from atc_nf_env.episode import run_episode
from atc_nf_env.kernel import N_RECORD, R_FLEW, R_X, R_Y
from atc_nf_env.policy import make_policy

#: The airspeed column of a table row, e.g. "-470–1054" (kt).
AIRSPEED_RANGE = re.compile(r"(-?\d+)–(-?\d+)$")


def _fly_with_figure(tmp_path, monkeypatch, capsys, *arguments: str):
    """Run ``atc-nf fly ... --plots`` and return the printed table and the airspeed figure
    (caught as it is saved)."""
    from matplotlib.figure import Figure

    saved: dict[str, Figure] = {}
    original = Figure.savefig

    def keep(figure, path, *args, **kwargs):
        saved[str(path)] = figure
        return original(figure, path, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep)
    assert main(["fly", *arguments, "--plots", str(tmp_path)]) == 0
    (figure,) = [f for path, f in saved.items() if path.endswith("_airspeed.png")]
    return capsys.readouterr().out, figure


def _plotted_extremes(figure) -> dict[str, tuple[float, float]]:
    """Per aircraft ("aircraft i"), the lowest and highest airspeed drawn: its lines', its
    markers' and its bands' vertices, read back from the axes' artists."""
    (ax,) = figure.axes
    values: dict[str, list[np.ndarray]] = {}
    for line in ax.lines:
        key = line.get_gid() or line.get_label()
        if key.startswith("aircraft "):
            values.setdefault(key, []).append(np.asarray(line.get_ydata(), dtype=float))
    for collection in ax.collections:
        key = collection.get_gid() or collection.get_label()
        if key and key.startswith("aircraft "):
            values.setdefault(key, []).extend(path.vertices[:, 1] for path in collection.get_paths())
    return {key: (min(v.min() for v in vs), max(v.max() for v in vs)) for key, vs in values.items()}


def _table_ranges(table: str) -> dict[str, tuple[int, int]]:
    """Per row of the fly table ("0", "1", ..., "all"), its airspeed range (kt)."""
    ranges = {}
    for line in table.splitlines():
        cells = line.split()
        if cells and (cells[0].isdigit() or cells[0] == "all") and (found := AIRSPEED_RANGE.search(line)):
            ranges[cells[0]] = (int(found[1]), int(found[2]))
    return ranges


def test_fly_s_airspeed_figure_reaches_the_table_s_extremes(tmp_path, monkeypatch, capsys) -> None:
    # The flight: the table said -470 kt, the figure bottomed at -208 kt.
    table, figure = _fly_with_figure(tmp_path, monkeypatch, capsys, "--policy", "nf", "--scenario",
                                     "converging-6", "--seed", "3")
    ranges = _table_ranges(table)
    plotted = _plotted_extremes(figure)
    assert set(plotted) == {f"aircraft {i}" for i in range(6)}
    for i in range(6):
        low, high = plotted[f"aircraft {i}"]
        assert (round(low), round(high)) == ranges[str(i)], f"aircraft {i}"
    lowest = min(low for low, _ in plotted.values())
    highest = max(high for _, high in plotted.values())
    assert (round(lowest), round(highest)) == ranges["all"]
    assert ranges["all"][0] < -400  # the sub-step spike the figure used to miss
    # Nothing drawn is clipped by the axis.
    bottom, top = figure.axes[0].get_ylim()
    assert bottom < lowest and highest < top


def test_the_figure_s_extremes_are_the_run_s_bit_for_bit() -> None:
    from atc_nf_env.plotting import airspeed_figure

    result = run_episode(make_policy("nf"), "converging-6", seed=3, record_every=1)
    figure = airspeed_figure(result)
    plotted = _plotted_extremes(figure)
    _, low, high = tables.per_aircraft(result)
    for i in range(6):
        assert plotted[f"aircraft {i}"] == (low[i], high[i])
    m = result.metrics
    assert min(p[0] for p in plotted.values()) == m.airspeed_min_kt
    assert max(p[1] for p in plotted.values()) == m.airspeed_max_kt
    assert not any("between the records" in t.get_text() for t in figure.axes[0].texts)


def test_a_sparse_recording_s_figure_says_what_it_leaves_out() -> None:
    from atc_nf_env.plotting import airspeed_figure

    result = run_episode(make_policy("nf"), "converging-6", seed=3, record_every=40)
    m = result.metrics
    notes = [t.get_text() for t in airspeed_figure(result).axes[0].texts]
    assert notes == [f"between the records the airspeed reached {m.airspeed_min_kt:.0f}–"
                     f"{m.airspeed_max_kt:.0f} kt (not drawn)"]


# -- the table in bounded memory (item 15) ---------------------------------------------------

def _all_pairs_closest_nm(records: np.ndarray) -> np.ndarray:
    """The table's closest approach as it was computed before: every pair at every record."""
    n = records.shape[1]
    flew = records[:, :, R_FLEW] > 0
    xy = records[:, :, [R_X, R_Y]]
    distance = np.hypot(*(xy[:, :, None, :] - xy[:, None, :, :]).transpose(3, 0, 1, 2))
    both = flew[:, :, None] & flew[:, None, :]
    both &= ~np.eye(n, dtype=bool)[None]
    masked = np.where(both, distance, np.inf).min(axis=(0, 2))
    return np.where(np.isfinite(masked), masked, np.nan)


@pytest.mark.parametrize("scenario, seed", [("converging-4", 0), ("converging-6", 3)])
@pytest.mark.parametrize("block", [None, 7, 1])  # None: the default blocks
def test_closest_approach_is_the_all_pairs_one_bit_for_bit(monkeypatch, scenario, seed, block) -> None:
    result = run_episode(make_policy("nf"), scenario, seed=seed, record_every=1)
    if block is not None:
        monkeypatch.setattr(tables, "PAIR_BLOCK_ELEMENTS", block)
    records = result.records
    np.testing.assert_array_equal(tables.closest_approach_nm(records), _all_pairs_closest_nm(records))


@settings(max_examples=60, deadline=None)
@given(n_records=st.integers(1, 9), n=st.integers(1, 7), block=st.integers(1, 80),
       seed=st.integers(0, 2**32 - 1))
def test_closest_approach_on_any_recording(n_records, n, block, seed) -> None:
    rng = np.random.default_rng(seed)
    records = np.zeros((n_records, n, N_RECORD))
    records[:, :, [R_X, R_Y]] = rng.normal(0.0, 50.0, (n_records, n, 2))
    records[:, :, R_FLEW] = rng.random((n_records, n)) < 0.7  # some records of some aircraft not flown
    old = tables.PAIR_BLOCK_ELEMENTS
    try:
        tables.PAIR_BLOCK_ELEMENTS = block
        np.testing.assert_array_equal(tables.closest_approach_nm(records), _all_pairs_closest_nm(records))
    finally:
        tables.PAIR_BLOCK_ELEMENTS = old


def test_the_table_s_memory_does_not_grow_with_the_records() -> None:
    # 1500 records of 120 aircraft: every pair at once took over 600 MB.
    rng = np.random.default_rng(0)
    records = np.zeros((1500, 120, N_RECORD))
    records[:, :, [R_X, R_Y]] = rng.normal(0.0, 100.0, (1500, 120, 2))
    records[:, :, R_FLEW] = 1.0
    tracemalloc.start()
    try:
        tables.per_aircraft(SimpleNamespace(records=records))  # what fly_table calls
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # A few blocks of PAIR_BLOCK_ELEMENTS distances (8 MB each) and (R, N) flags, not R·N² distances.
    assert peak < 64 * 2**20, f"{peak / 2**20:.0f} MB"


#: The fly tables of ``atc-nf fly --policy nf`` before the table was computed in blocks (all
#: but the timing line, whose seconds vary).
TODAY: dict[tuple[str, str], list[str]] = {
    ("converging-4", "0"): [
        'nf on converging-4, seed 0, wind (-1.3, -9.3) kt (σ 5.17 m/s)',
        'aircraft  home  flight min  path nm  closest nm  airspeed kt',
        '0         yes         84.5      505        10.5    -323–1054',
        '1         yes         72.7      499        10.4    -431–1054',
        '2         yes         91.1      505        10.4       9–1054',
        '3         no         240.0      497        10.5       9–1054',
        'all       3/4                              10.4    -431–1054',
        'mean flight time of the 3 aircraft home: 82.7 min',
        'losses of separation (< 5 nm): 0; steps outside [366, 540] kt: '
        '4592 of 5859 (worst by 797 kt)',
        'home: no = still flying at the time limit; left = left the workspace. flight min of an aircraft '
        'not home is its time flown.',
    ],
    ("converging-6", "3"): [
        'nf on converging-6, seed 3, wind (-20.0, +6.5) kt (σ 5.17 m/s)',
        'aircraft  home  flight min  path nm  closest nm  airspeed kt',
        '0         yes         68.5      508        10.1       9–1054',
        '1         no         240.0      518        10.3      17–1054',
        '2         no         240.0      511        10.3    -470–1054',
        '3         no         240.0      499        10.3    -463–1054',
        '4         no         240.0      510        10.2    -454–1054',
        '5         yes         73.6      499        10.1       9–1054',
        'all       2/6                              10.1    -470–1054',
        'mean flight time of the 2 aircraft home: 71.0 min',
        'losses of separation (< 5 nm): 0; steps outside [366, 540] kt: '
        '11331 of 13225 (worst by 836 kt)',
        'home: no = still flying at the time limit; left = left the workspace. flight min of an aircraft '
        'not home is its time flown.',
    ],
}


@pytest.mark.parametrize("scenario, seed", [("converging-4", "0"), ("converging-6", "3")])
def test_the_fly_table_prints_today_s_numbers(capsys, scenario, seed) -> None:
    assert main(["fly", "--policy", "nf", "--scenario", scenario, "--seed", seed]) == 0
    printed = [line for line in capsys.readouterr().out.splitlines() if not line.startswith("flew ")]
    assert printed == TODAY[(scenario, seed)]
