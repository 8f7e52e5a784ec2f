"""How much of the demo's end point is rounding: ``python -m bench.demo_rounding`` (about 2 minutes).

The demo's default teach is fitted with its detected pixels moved by a tiny Gaussian (1e-7 and
1e-6 px, eight seeds each, as a change of floating-point rounding in the fit would move its
result), and each fit repeated under the lateral-gain law with images in the loop, as
``hbvs demo`` does. It prints the fit's n* change and the run's final position error for each:
the digits that change are not an accuracy figure.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

import hbvs_cli.stages.fit as fit_stage
from hbvs_cli.io.run_file import read_run
from hbvs_cli.report.build import build_report
from hbvs_cli.stages.console import Console
from hbvs_cli.stages.fit import FitOptions, run_fit
from hbvs_cli.stages.repeat import RepeatOptions, run_repeat
from hbvs_cli.stages.teach import TeachOptions, run_teach

SIGMAS_PX = (0.0, 1e-7, 1e-6)
SEEDS = range(1, 9)


def end_point(folder: Path, teach: Path, sigma_px: float, seed: int) -> tuple[np.ndarray, float]:
    """The fit's n* and the lateral-gain repeat's final position error (m), the detected
    pixels moved by ``sigma_px`` (seeded) before fitting."""
    fitted = fit_stage._fit
    normal = {}

    def moved(arrays, *args, **kwargs):
        if sigma_px > 0.0:
            noise = np.random.default_rng(seed).normal(0.0, sigma_px, arrays["pixels"].shape)
            arrays = dict(arrays, pixels=arrays["pixels"] + noise)
        result = fitted(arrays, *args, **kwargs)
        normal["n"] = result.normal
        return result

    quiet = Console(quiet=True)
    fit, run = folder / f"fit-{sigma_px:g}-{seed}.mcap", folder / f"run-{sigma_px:g}-{seed}.mcap"
    fit_stage._fit = moved
    try:
        run_fit(FitOptions(input=str(teach), output=str(fit)), quiet)
    finally:
        fit_stage._fit = fitted
    run_repeat(RepeatOptions(input=str(fit), output=str(run), sim=True, law="lateral-gain"), quiet)
    return normal["n"], float(build_report(read_run(run)).to_dict()["pose_error"]["position_m"]["final"])


def main() -> int:
    with tempfile.TemporaryDirectory() as folder:
        teach = Path(folder) / "teach.mcap"
        run_teach(TeachOptions(output=str(teach)), Console(quiet=True))
        base, base_end = end_point(Path(folder), teach, 0.0, 0)
        print(f"unmoved: final position error {100 * base_end:.4f} cm")
        for sigma in SIGMAS_PX[1:]:
            ends = []
            for seed in SEEDS:
                normal, end = end_point(Path(folder), teach, sigma, seed)
                turn = np.degrees(np.arctan2(np.linalg.norm(np.cross(normal, base)), float(normal @ base)))
                ends.append(end)
                print(f"pixels moved {sigma:g} px, seed {seed}: n* {turn:.1e} deg, final position error {100 * end:.4f} cm")
            print(f"pixels moved {sigma:g} px: final position error {100 * min(ends):.4f} to {100 * max(ends):.4f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
