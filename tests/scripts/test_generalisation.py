"""scripts/generalisation.sh: bad input is named in one line before anything is written (the protocol itself runs
for an hour and more; its smoke run is in docs/reproduce.md)."""

from __future__ import annotations

from pathlib import Path

from tests.scripts.test_reproduce import run_script

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "generalisation.sh"


def test_an_unknown_training_setting_phase_or_seed_or_an_empty_value_is_named(tmp_path):
    for variables, message in (
            ({"TRAINED_ON": "random_obstacles fixed4"}, "TRAINED_ON: unknown training setting 'fixed4'; expected"),
            ({"PHASES": "learners,plots"}, "PHASES='learners,plots': 'plots' is not a phase; expected some of "
                                           "learners,evals,arvi,tables"),
            ({"SEEDS": "4-2"}, "SEEDS='4-2': '4-2' is not a seed or a rising range"),
            # set but empty: refused, not taken for the default
            ({"SEEDS": ""}, "SEEDS is empty: expected seeds, e.g. 0,1,2 or 0-19 or 0-4,10, or unset for 0-4"),
            ({"ARVI_SEEDS": ""}, "ARVI_SEEDS is empty: expected seeds"),
            ({"ARVI_NODES": ""}, "ARVI_NODES is empty: expected a number of nodes, or unset for 25000"),
            ({"JOBS": "two"}, "JOBS='two': expected a whole number from 1 on")):
        result = run_script(tmp_path, **variables, OUT="out", script=SCRIPT)
        assert result.returncode == 2 and result.stderr.count("\n") == 1 and message in result.stderr, result.stderr
    assert not (tmp_path / "out").exists()
