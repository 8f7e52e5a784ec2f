"""The figure of docs/sweep-study.md: convergence rate against dhat(0)/d*, per law.

    python docs/sweep-study/convergence_vs_depth.py study-points/runs.csv study-images/runs.csv

reads the sweeps' tables (``hbvs sweep ... -o study-points/``, ``-o study-images/``), writes
``docs/sweep-study/convergence_vs_depth.png`` and prints the rates it plots.
"""

from __future__ import annotations

import csv
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

LAWS = ("paper", "lateral-gain", "non-adaptive", "kanayama")
COLOURS = {"paper": "tab:blue", "lateral-gain": "tab:red", "non-adaptive": "tab:gray", "kanayama": "tab:green"}


def convergence(paths: list[str]) -> dict[tuple[str, float], dict[str, dict[float, list[bool]]]]:
    """(perception, pixel noise) -> law -> dhat0 factor -> converged flags of its runs."""
    runs: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for path in paths:
        with open(path, newline="") as handle:
            for row in csv.DictReader(handle):
                group = (row["perception"], float(row["pixel_noise"]))
                runs[group][row["law"]][float(row["dhat0_factor"])].append(row["converged"].lower() == "true")
    return runs


def main(paths: list[str]) -> None:
    runs = convergence(paths)
    groups = sorted(runs)
    figure, axes = plt.subplots(1, len(groups), figsize=(3.6 * len(groups), 3.4), sharey=True, squeeze=False)
    for axis, group in zip(axes[0], groups):
        count = 0
        for law in LAWS:
            factors = sorted(runs[group][law])
            rates = [100.0 * sum(runs[group][law][f]) / len(runs[group][law][f]) for f in factors]
            count += sum(len(runs[group][law][f]) for f in factors)
            axis.plot(factors, rates, "o-", color=COLOURS[law], label=law)
            print(f"{group[0]:6s} {group[1]:g} px {law:13s} " + "  ".join(f"{f:g}: {r:5.1f} %" for f, r in zip(factors, rates)))
        axis.set_title(f"{group[0]}, {group[1]:g} px ({count} runs)", fontsize=10)
        axis.set_xscale("log", base=2)
        axis.set_xticks([0.25, 0.5, 1, 2, 4], ["1/4", "1/2", "1", "2", "4"])
        axis.set_xlabel("dhat(0) / d*")
        axis.grid(alpha=0.3)
    axes[0][0].set_ylabel("converged (%)")
    axes[0][0].set_ylim(-5, 105)
    axes[0][0].legend(fontsize=8)
    figure.tight_layout()
    out = Path(__file__).with_name("convergence_vs_depth.png")
    figure.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1:])
