"""Print the comparison table of run_ttenv.py's and run_aia.py's records (any python with numpy)::

    python scripts/ttenv_compare/compare.py /tmp/ttenv_compare/*.json > table.md

Records pair up by (version, policy, map; ttenv's obstacles02 is aia's obstacles4); runs of one side with the
same key (other seeds) pool their episodes. Each cell is the mean
over episodes with its standard error, ttenv then aia, and z = (aia - ttenv) / sqrt(se_ttenv^2 + se_aia^2);
|z| >= 3 is flagged with `!` (for the observed rate the
standard errors come from the pooled rate). Episodes where ttenv raised are left out from the step they raised on.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from common import EPISODE_KEYS, STEP_KEYS

STEPS = (0, 1, 10, 50, 100)  # t = 0: after the reset (ttenv has observed and updated, aia has not)
ROWS = (("logdet", "log det Sigma, updated b(t given t)"), ("logdet_feat", "log det Sigma, what features read"),
        ("observed", "observed"), ("dist_rt", "robot-target distance"), ("belief_err", "belief error (mean-target)"),
        ("target_speed", "target speed"), ("collisions", "robot collisions so far"),
        ("robot_travel", "robot travel from its start"), ("target_from_start", "target distance from robot start"))
MAPS = {"obstacles02": "obstacles4"}


def stat(values) -> tuple[float, float, int]:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return np.nan, np.nan, 0
    return v.mean(), v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else np.nan, len(v)


def cell(a, b, binary: bool = False) -> str:
    (ma, sa, na), (mb, sb, nb) = a, b
    if binary and na and nb:  # a 0/1 mean: standard errors from the pooled rate (a side with no hit has se 0)
        pooled = (ma * na + mb * nb) / (na + nb)
        sa, sb = (np.sqrt(pooled * (1 - pooled) / n) for n in (na, nb))
    scale = max(np.hypot(sa, sb), 1e-6 * (1 + abs(ma) + abs(mb)))  # no z of 1e8 between two constants
    z = (mb - ma) / scale
    flag = "!" if abs(z) >= 3 else ""
    return f"{ma:.3g}±{sa:.2g} / {mb:.3g}±{sb:.2g} ({z:+.1f}{flag})"


def table(t: dict, a: dict) -> str:
    extra = f" (aia with {', '.join(a['overrides'])})" if a.get("overrides") else ""
    lines = [f"### v{t['version']} {t['policy']} on {t['map']}{extra}: ttenv {t['episodes']} episodes"
             f" / aia {a['episodes']}; ttenv raised in {int(np.isfinite(np.array(t['crash_step'], dtype=float)).sum())}"
             f" {t.get('errors') or ''}", "",
             "| quantity | " + " | ".join(f"t = {s}" for s in STEPS) + " |", "|---" * (len(STEPS) + 1) + "|"]
    for key, name in ROWS:
        if key not in t or key not in a:  # records written before these rows existed
            continue
        ta, aa = np.array(t[key], dtype=float), np.array(a[key], dtype=float)
        lines.append(f"| {name} | " + " | ".join(cell(stat(ta[:, s]), stat(aa[:, s]), key == "observed")
                                                 for s in STEPS) + " |")
    for key, name in (("init_rb", "initial robot-belief distance"), ("init_bt", "initial belief-target distance")):
        lines.append(f"| {name} | {cell(stat(t[key]), stat(a[key]))} |" + " |" * (len(STEPS) - 1))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("records", nargs="+", type=Path, help="run_ttenv.py's and run_aia.py's JSON records")
    records = parser.parse_args().records
    missing = [path for path in records if not path.is_file()]
    if missing:
        parser.error(f"no record at {str(missing[0])!r}: expected the JSON files run_ttenv.py and run_aia.py write")
    runs = []
    for path in records:  # detour_check.py's states may sit in the same folder: not a run record
        record = json.loads(path.read_text())
        if isinstance(record, dict) and "side" in record:
            runs.append(record)
        else:
            print(f"compare.py: {path} is not a run record (run_ttenv.py's or run_aia.py's); left out",
                  file=sys.stderr)
    key = lambda r: (r["version"], r["policy"], MAPS.get(r["map"], r["map"]))  # noqa: E731
    ttenv, aia = {}, {}
    for r in runs:  # runs of the same side and key (other seeds) pool their episodes
        side = ttenv if r["side"] == "ttenv" else aia
        if key(r) in side:
            pooled = side[key(r)]
            for k in STEP_KEYS + EPISODE_KEYS:
                if k in pooled and k in r:
                    pooled[k] = pooled[k] + r[k]
                else:
                    pooled.pop(k, None)
            pooled["episodes"] += r["episodes"]
            for name, n in r.get("errors", {}).items():
                pooled["errors"][name] = pooled["errors"].get(name, 0) + n
        else:
            side[key(r)] = r
    print("cells: ttenv mean±se / aia mean±se (z); ! marks |z| >= 3\n")
    policies = ("stay", "spin", "straight", "random")
    for k in sorted(ttenv.keys() & aia.keys(), key=lambda k: (k[0], k[2], policies.index(k[1]))):
        print(table(ttenv[k], aia[k]) + "\n")


if __name__ == "__main__":
    main()
