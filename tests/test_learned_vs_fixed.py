"""The study's paired comparison: each policy against the fixed-rate front at its own bytes, then the difference."""

import numpy as np
import pytest

from studies.fronts import FIXED_RATE, paired
from studies.learned_vs_fixed import pairs_table


def cell_rows(cell: str, a: tuple[float, float], b: tuple[float, float]) -> list[dict]:
    """A cell whose fixed-rate front is the straight line completion = 50 + MB (never at 0 MB, always at 40)."""
    rows = [{"cell": cell, "policy": name, "mb": mb, "completion": 50.0 + mb}
            for name, mb in zip(FIXED_RATE, np.linspace(0.0, 40.0, len(FIXED_RATE)))]
    rows.append({"cell": cell, "policy": "A", "mb": a[0], "completion": a[1]})
    rows.append({"cell": cell, "policy": "B", "mb": b[0], "completion": b[1]})
    return rows


def test_paired_difference_is_taken_at_each_policys_own_bytes():
    # A: 5 points above the front at 10 MB; B: 2 points above it at 30 MB, though B completes more.
    rows = cell_rows("x:1", (10.0, 65.0), (30.0, 82.0)) + cell_rows("x:2", (10.0, 64.0), (30.0, 81.0))
    assert paired(rows, "A", "B") == pytest.approx([3.0, 3.0])
    assert paired(rows, "B", "A") == pytest.approx([-3.0, -3.0])


def test_paired_uses_only_cells_both_played():
    rows = cell_rows("x:1", (10.0, 65.0), (30.0, 82.0)) + [
        r for r in cell_rows("x:2", (10.0, 64.0), (30.0, 81.0)) if r["policy"] != "B"]
    assert len(paired(rows, "A", "B")) == 1
    assert "| 1 | - |" in pairs_table(rows, [("A", "B")])


def test_pairs_table_marks_a_difference_beyond_two_standard_errors():
    rows = []
    for k, gain in enumerate((3.0, 3.5, 2.5, 3.2)):
        rows += cell_rows(f"x:{k}", (10.0, 60.0 + gain), (10.0, 60.0))
    assert "**> 2 SE**" in pairs_table(rows, [("A", "B")])
