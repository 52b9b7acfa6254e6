"""Reproduction of Farenzena & Trierweiler (2012), Tables 1-3."""
import json

import numpy as np
import pytest

from valvediag.paper import tables as paper


def test_grid_sizes_as_printed():
    assert len(paper.table1_grid()["kc"]) == 73_920      # the paper states 52,800
    assert len(paper.table2_grid()["kc"]) == 13_440
    assert len(paper.table3_grid()["kc"]) == 840
    assert paper.KC_GRID.size == 14 and paper.TI_RATIO_GRID.size == 8
    g = paper.table1_grid()
    assert np.unique((g["J"] / g["S"]).round(6)).tolist() == [0.5, 0.6, 0.7, 0.8, 0.9, 1.0]


def _subset(grid, step):
    return {k: v[::step] for k, v in grid.items()}


@pytest.fixture(scope="module")
def tables12():
    t1 = paper.run_grid(_subset(paper.table1_grid(), 61), valve="kano", sample_time=0.1,
                        methods=("paper", "robust"))
    t2 = paper.run_grid(_subset(paper.table2_grid(), 17), valve="backlash", sample_time=0.1,
                        methods=("paper", "robust"))
    return t1, t2


def test_table1_stiction_paper_method(tables12):
    """Paper: 99.8 % stiction, 0.2 % undecided, no backlash (1,212 of 73,920)."""
    bi = tables12[0][:, 0]
    assert np.mean(bi <= 1.5) >= 0.998
    assert np.sum(bi >= 3.0) == 0


def test_table2_backlash_paper_method(tables12):
    """Paper: 100 % backlash (791 of 13,440); at least 99.5 %."""
    assert np.mean(tables12[1][:, 0] >= 3.0) >= 0.995


def test_tables_1_2_robust_method(tables12):
    lo, hi = paper.THRESHOLDS["robust"]
    assert np.mean(tables12[0][:, 1] <= lo) >= 0.99
    assert np.mean(tables12[1][:, 1] >= hi) >= 0.99


def test_every_record_has_five_cycles(tables12):
    for out in tables12:
        assert np.all(out[:, 2] >= 4.0)


def test_table3_falling_trend():
    res = paper.reproduce_paper("paper", tables=(3,))
    rows = {r["sample_time"]: r["backlash"] for r in res.table3}
    assert all(rows[st] == 100.0 for st in (0.1, 0.2, 0.5))
    shares = [rows[st] for st in paper.TABLE3_SAMPLE_TIMES]
    assert all(a >= b for a, b in zip(shares, shares[1:]))     # never rises with the sample time
    assert rows[5.0] < 100.0
    doc = json.loads(res.dumps())
    assert set(doc) == {"table1", "table2", "table3", "seconds", "method"}
    assert doc["table3"][0] == {"sample_time": 0.1, "n": 120, "backlash": 100.0}
    assert "Table 3" in res.report()


def test_unknown_method():
    with pytest.raises(ValueError, match="method"):
        paper.reproduce_paper("fast")
