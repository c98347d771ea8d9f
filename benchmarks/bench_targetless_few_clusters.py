"""The targetless check's test with few or many, equal or unequal clusters (the physical
corners and photometric blocks of a drive): false alarms at the 1 % level and power
against a known change, on synthetic clustered least-squares problems with a known
answer (3 directions fitted; clusters of 3-30 alike rows, 15 each, or 2-200, sharing one
error).

Rules: ``former`` (round 5: G - 2 directions, those whose spread came out narrowest, an
effective count up to G); ``spread`` (round 6: at most G - m - 1 directions, the best
determined by the design, Hotelling's T^2 against F with Kish's count up to G - m + 1);
``bootstrap`` (round 7: the same directions and T^2, referred to the wild cluster
bootstrap with restricted scores, ``statistic.wild_cluster_bootstrap``). Power: the truth
moved by ``--shift`` times the estimate's spread (per axis, over 200 draws without change)
along (1, 1, 1). Pure numpy.

    .venv/bin/python benchmarks/bench_targetless_few_clusters.py --draws 1000
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bench_targetless import clopper_pearson

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "drift"))
from test_statistic import clustered_problem, few_cluster_p_values


def spread_of_estimate(rng: np.random.Generator, G: int, sizes: str) -> float:
    """The RMS per axis of the estimate over 200 draws without change."""
    th = np.array([clustered_problem(rng, G, sizes=sizes)[0] for _ in range(200)])
    return float(np.sqrt(np.mean(th**2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=1000, help="problems per row (and as many for the power)")
    ap.add_argument("--boot-draws", type=int, default=999, help="the bootstrap's draws per problem")
    ap.add_argument("--clusters", default="4,5,6,8,12,16,20,30")
    ap.add_argument("--sizes", default="unequal,equal", help="unequal (3-30 rows), equal (15), wild (2-200)")
    ap.add_argument("--directions", default="1,3", help="at most this many directions tested")
    ap.add_argument("--rules", default="spread,bootstrap")
    ap.add_argument("--shift", type=float, default=3.0, help="the change for the power, in spreads")
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    rules = args.rules.split(",")
    print(
        "| clusters G (3 fitted) | sizes | directions (at most) | rule | tested in "
        "| false alarms at 1 % (95 % interval) | median p | power at 1 % |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for G in (int(x) for x in args.clusters.split(",")):
        for sizes in args.sizes.split(","):
            truth = args.shift * spread_of_estimate(rng, G, sizes) * np.ones(3)
            for most in (int(x) for x in args.directions.split(",")):
                null: dict[str, list[float]] = {r: [] for r in rules}
                alt: dict[str, list[float]] = {r: [] for r in rules}
                for _ in range(args.draws):
                    for rule, value in few_cluster_p_values(
                        rng, G, directions=most, sizes=sizes, draws=args.boot_draws
                    ).items():
                        if rule in null:
                            null[rule].append(value)
                    for rule, value in few_cluster_p_values(
                        rng, G, directions=most, sizes=sizes, truth=truth, draws=args.boot_draws
                    ).items():
                        if rule in alt:
                            alt[rule].append(value)
                for rule in rules:
                    a, b = np.array(null[rule]), np.array(alt[rule])
                    row = f"| {G} | {sizes} | {most} | {rule} | {len(a)}/{args.draws} |"
                    if not len(a):
                        print(row + " - | - | - |")
                        continue
                    n1 = int((a < 0.01).sum())
                    lo, hi = clopper_pearson(n1, len(a))
                    rate = f"{100 * n1 / len(a):.2f} % ({100 * lo:.2f}-{100 * hi:.2f} %)"
                    power = f"{100 * float(np.mean(b < 0.01)):.1f} %"
                    print(f"{row} {rate} | {float(np.median(a)):.2f} | {power} |", flush=True)


if __name__ == "__main__":
    main()
