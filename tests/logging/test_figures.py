"""The learning curves' markdown table: final levels, tails and the first x reaching each baseline."""

from __future__ import annotations

import numpy as np

from aia.logging.curves import Curve
from aia.logging.figures import results_table


def test_the_table_gives_each_group_its_final_level_tail_and_first_x_reaching_each_baseline():
    rising = Curve("adfq", x=np.array([100.0, 200.0, 300.0]), mean=np.array([1.0, 5.0, 9.0]),
                   std=np.array([0.0, 1.0, 2.0]), runs=np.array([2, 2, 2]), tails=np.array([8.0, 10.0]))
    flat = Curve("dqn", x=np.array([100.0, 200.0, 300.0]), mean=np.array([2.0, 2.0, 3.0]),
                 std=np.zeros(3), runs=np.array([3, 3, 1]), tails=np.array([3.0, 3.0, 3.0]))
    table = results_table([rising, flat], "eval/score", "frame", [("ARVI", 4.0, 0.5, 10), ("ARVI 2 m", 8.5, 1.0, 10)])
    assert table.splitlines() == [
        "| group | runs | final eval/score (mean +- std over runs) | last 10% of evaluations (mean +- std over runs) |"
        " training frames to reach ARVI (4.0 +- 0.5) | training frames to reach ARVI 2 m (8.5 +- 1.0) |",
        "|---|---:|---:|---:|---:|---:|",
        "| adfq | 2 | 9.0 +- 2.0 | 9.0 +- 1.0 | 200 | 300 |",
        "| dqn | 3 | 3.0 +- 0.0 | 3.0 +- 0.0 | never | never |"]
    lower = results_table([rising], "eval/belief_error", "episode", [("ARVI", 4.0, 0.5, 10)], lower_better=True)
    assert lower.splitlines()[0].endswith(" training episodes to fall to ARVI (4.0 +- 0.5) |")
    assert lower.splitlines()[2].endswith(" | 100 |")  # 1.0 is already below 4.0 at the first x
