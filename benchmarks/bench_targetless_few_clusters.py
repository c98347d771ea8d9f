"""The targetless check's test with few clusters (the physical corners of a short drive):
false alarms at the 1 % level on synthetic clustered problems with a known answer, by
the former rule (G - 2 directions, those whose spread came out narrowest, an effective
count up to G) and by the spread's degrees of freedom (``statistic.spread_dof``: G - m
left for m directions fitted, at most G - m - 1 tested, the best determined by the
design, a count up to G - m + 1). Pure numpy, a few seconds.

    .venv/bin/python benchmarks/bench_targetless_few_clusters.py --draws 2000
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bench_targetless import clopper_pearson

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "drift"))
from test_statistic import few_cluster_p_values


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=2000, help="problems per cluster count")
    ap.add_argument("--clusters", default="4,5,6,8,12,20")
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    print("| clusters G (3 directions fitted) | rule | tested in ", end="")
    print("| false alarms at 1 % (95 % interval) | median p |")
    print("|---|---|---|---|---|")
    for G in (int(x) for x in args.clusters.split(",")):
        p: dict[str, list[float]] = {"former": [], "spread": []}
        for _ in range(args.draws):
            for rule, value in few_cluster_p_values(rng, G).items():
                p[rule].append(value)
        for rule, values in p.items():
            if not values:
                print(f"| {G} | {rule} | 0/{args.draws} | - | - |")
                continue
            a = np.array(values)
            n1 = int((a < 0.01).sum())
            lo, hi = clopper_pearson(n1, len(a))
            rate = f"{100 * n1 / len(a):.2f} % ({100 * lo:.2f}-{100 * hi:.2f} %)"
            print(f"| {G} | {rule} | {len(a)}/{args.draws} | {rate} | {float(np.median(a)):.2f} |")


if __name__ == "__main__":
    main()
