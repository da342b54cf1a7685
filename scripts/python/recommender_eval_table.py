#!/usr/bin/env python3
"""The held-out table of the recommender results (docs/src/experiments/recommender.md): runs `jsae recommender-eval` on
every recommender run under the given directories (a sweep's `runs/`, or run directories) and
prints one markdown row per policy: the learned policies per algorithm, then the reference
policies, each as the mean over the runs with the lowest and highest run in brackets.

Usage: scripts/python/recommender_eval_table.py [--jsae PATH] [--k K] DIR [DIR ...]
"""

import argparse
import json
import os
import subprocess
import sys
from collections import defaultdict


def run_dirs(roots):
    for root in roots:
        for here, dirs, files in sorted(os.walk(root)):
            dirs.sort()
            if "config.toml" in files and os.path.isdir(os.path.join(here, "checkpoints")):
                yield here


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dirs", nargs="+")
    p.add_argument("--jsae", default="target/release/jsae")
    p.add_argument("--k", type=int, default=10)
    a = p.parse_args()
    rows = defaultdict(list)
    meta = None
    for run in run_dirs(a.dirs):
        out = subprocess.run([a.jsae, "recommender-eval", "--run", run, "--k", str(a.k)],
                             capture_output=True, text=True)
        if out.returncode != 0:
            sys.exit(f"{run}: {out.stderr.strip()}")
        r = json.loads(out.stdout)
        meta = meta or r
        for policy in r["policies"]:
            name = policy["policy"]
            key = f"{r['algo']} (learned)" if name == "learned" else name
            rows[key].append(policy)
    if not rows:
        sys.exit("no run directories with checkpoints found")
    k = a.k
    print(f"held-out sessions {meta['sessions']}, queries {meta['queries']} "
          f"(purchases outside the catalogue: {meta['outside_catalogue']}), k = {k}\n")
    print(f"| policy | runs | HR@{k} | NDCG@{k} | MRR@{k} | coverage@{k} | simulated return |")
    print("|---|---|---|---|---|---|---|")
    order = sorted(rows, key=lambda n: (not n.endswith("(learned)"), n))
    for name in order:
        v = rows[name]

        def cell(field, digits):
            xs = [x[field] for x in v]
            m = sum(xs) / len(xs)
            if len(set(xs)) == 1:
                return f"{m:.{digits}f}"
            return f"{m:.{digits}f} [{min(xs):.{digits}f}, {max(xs):.{digits}f}]"
        print(f"| {name} | {len(v)} | {cell(f'hr_at_{k}', 3)} | {cell(f'ndcg_at_{k}', 3)} | "
              f"{cell(f'mrr_at_{k}', 3)} | {cell(f'coverage_at_{k}', 3)} | {cell('return_mean', 2)} |")


if __name__ == "__main__":
    main()
