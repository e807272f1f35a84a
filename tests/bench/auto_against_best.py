#!/usr/bin/env python3
"""`--integrator auto` against the best of the other methods, from `prism bench` results.

    python3 tests/bench/auto_against_best.py RESULTS.csv... [--best uniform,hero,hero+prepass,gradient]

Reads one or more results.csv files of `prism bench` runs of the same scenes with the same
reference cache (so the errors are against the same references), and prints a markdown table:
per scene and budget, the method auto ran, auto's relMSE over that of the best of the --best
methods at auto's own seconds (each method's curve interpolated log-log between its budgets, as
client/evaluation.h does, and extrapolated along its last segment beyond them), and auto's ratio
to hero. Means over seeds, whole image.
"""
import argparse
import collections
import csv
import math
import sys


def error_at(curve, seconds):
    """The curve's relMSE at `seconds`, log-log interpolated; None when it has no usable point."""
    points = sorted((t, e) for t, e in curve if t > 0 and e > 0)
    if not points:
        return None
    if len(points) == 1:
        t, e = points[0]
        return e * t / seconds  # relMSE proportional to 1/time
    for (t0, e0), (t1, e1) in zip(points, points[1:]):
        if seconds <= t1 or (t1, e1) == points[-1]:
            slope = math.log(e1 / e0) / math.log(t1 / t0)
            return e0 * math.exp(slope * math.log(seconds / t0))
    return None


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+")
    parser.add_argument("--best", default="uniform,hero,hero+prepass,gradient")
    args = parser.parse_args()
    best_methods = args.best.split(",")

    # (scene, method, budget) -> [seconds], [rel_mse], and what auto ran.
    seconds = collections.defaultdict(list)
    errors = collections.defaultdict(list)
    ran = collections.defaultdict(set)
    scenes, budgets = [], []
    for path in args.results:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row["region"] != "image":
                    continue
                key = (row["scene"], row["method"], row["budget"])
                seconds[key].append(float(row["seconds"]))
                errors[key].append(float(row["rel_mse"]))
                ran[key].add(row["ran"])
                if row["scene"] not in scenes:
                    scenes.append(row["scene"])
                if row["budget"] not in budgets:
                    budgets.append(row["budget"])

    def mean(values):
        return sum(values) / len(values)

    def curve(scene, method):
        return [(mean(seconds[(scene, method, b)]), mean(errors[(scene, method, b)]))
                for b in budgets if (scene, method, b) in seconds]

    print("| scene | budget | auto ran | auto ÷ best (best) | auto ÷ hero |")
    print("|---|---|---|---|---|")
    worst = []
    for scene in scenes:
        for budget in budgets:
            key = (scene, "auto", budget)
            if key not in seconds:
                continue
            t, e = mean(seconds[key]), mean(errors[key])
            at = {m: error_at(curve(scene, m), t) for m in best_methods}
            at = {m: v for m, v in at.items() if v is not None and v > 0}
            if not at or e <= 0:
                continue
            best = min(at, key=at.get)
            hero = at.get("hero")
            ratio = e / at[best]
            worst.append((ratio, scene, budget))
            to_hero = f"{e / hero:.2f}" if hero else "–"
            print(f"| {scene} | {budget} | {', '.join(sorted(ran[key]))} | "
                  f"{ratio:.2f} ({best}) | {to_hero} |")
    if worst:
        within = sum(1 for r, _, _ in worst if r <= 1.10)
        print(f"\nWithin 10 % of the best: {within} of {len(worst)} (scene, budget) pairs; "
              f"worst {max(worst)[0]:.2f} ({max(worst)[1]}, {max(worst)[2]}).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
