#!/usr/bin/env python3
"""Summarises raw_vs_rectified.sh's ate.csv: per variant the median ATE over every (seed, start), and the paired
comparison with the rendered-rectified run of the same (seed, start) — the median of the ratios with a
bootstrap 90 % interval (resampling whole seeds, then starts within them, since starts of one seed share a
sequence). Usage: raw_vs_rectified.py OUT/ate.csv"""
import csv, random, statistics, sys
from collections import defaultdict

runs = defaultdict(dict)
for row in csv.DictReader(open(sys.argv[1])):
    runs[(row["seed"], int(row["start"]))][row["variant"]] = float(row["ate_mm"])
variants = ["rectified", "mild", "strong"]
seeds = sorted({seed for seed, _ in runs})
print(f"{len(seeds)} seeds, {len(runs)} (seed, start) pairs")
for v in variants:
    ates = [r[v] for r in runs.values() if v in r]
    print(f"{v:>10}: median ATE {statistics.median(ates):.4f} mm over {len(ates)} runs "
          f"[{min(ates):.4f}–{max(ates):.4f}]")
rng = random.Random(2026)
for v in variants[1:]:
    by_seed = defaultdict(list)
    for (seed, _), r in runs.items():
        if v in r and "rectified" in r:
            by_seed[seed].append(r[v] / r["rectified"])
    ratios = [x for xs in by_seed.values() for x in xs]
    boot = []
    for _ in range(4000):
        sample = []
        for seed in rng.choices(list(by_seed), k=len(by_seed)):
            sample += rng.choices(by_seed[seed], k=len(by_seed[seed]))
        boot.append(statistics.median(sample))
    boot.sort()
    per_seed = ", ".join(f"{s}: {statistics.median(x):.2f}" for s, x in sorted(by_seed.items()))
    worse = sum(x > 1 for x in ratios)
    print(f"{v:>10} / rectified: median ratio {statistics.median(ratios):.3f} "
          f"(90 % {boot[len(boot) // 20]:.3f}–{boot[-len(boot) // 20]:.3f}); worse in {worse} of {len(ratios)}; "
          f"per seed {per_seed}")
