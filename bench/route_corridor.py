"""The corridor route in closed loop (issue 47): position error along the route, its maximum
around each switch, how much the law's errors and commands step at a switch, the depth
estimate's relative error per segment, the end pose; exact
measurements, then seeds 0-9 with 0.1 px of noise on the taught pixels (a detector's on
rendered frames, as bench/CALIBRATION.md takes it) and 0.5 px on the repeat's.

    python -m bench.route_corridor [--plot docs/figures/route_corridor.png]

The taught targets' exact pixels (sim/route_world.py) stand in for a detector, so this
measures the route's method (segments, transitions, switches), not the detectors. ~2 min.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from hbvs_cli.core.control_settings import ControllerGains
from hbvs_cli.core.controller import AdaptiveTrackingController
from hbvs_cli.core.frames import compose_planar_pose, wrap_angle
from hbvs_cli.core.gains import noise_from_residual, suggest_gains
from hbvs_cli.core.simulator import ActuatorLimits
from hbvs_cli.settings.commands import DEFAULT_MAX_V, DEFAULT_MAX_W, DEFAULT_OFFSET
from hbvs_cli.sim.route_loop import run_route, switch_times
from hbvs_cli.sim.route_world import corridor_route
from hbvs_cli.stages.options import parse_offset

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # the taught views are a test oracle
from oracles import fit_route, taught_views  # noqa: E402

#: Taught frame period (s), control period (s), seconds either side of a switch, dhat(0) / d*_0,
#: seconds after which the start offset's transient is over.
TAUGHT_STEP, DT, AROUND_SWITCH_S, DHAT0_FACTOR, SETTLED_S = 0.2, 1.0 / 30.0, 1.0, 1.2, 5.0
#: Pixel noise (px, 1 sigma) of the taught frames' detections and of the repeat's.
TEACH_NOISE_PX, REPEAT_NOISE_PX = 0.1, 0.5


def corridor_run(teach_noise: float, pixel_noise: float, seed: int) -> dict:
    """One teach (``teach_noise`` px on its pixels), fit and repeat (``pixel_noise`` px) of the corridor, seeded."""
    route = corridor_route()
    rng = np.random.default_rng(seed)
    times = np.arange(0.0, route.profile.duration, TAUGHT_STEP)
    poses, spans, pixels = taught_views(route, times, teach_noise, rng)
    fitted = fit_route(route, times, pixels, spans)
    depths = np.array([route.worlds[s.target].reference_geometry(route.local_pose(s.target, poses[r]))[2]
                       for s, r in zip(fitted.segments, fitted.references)])
    noise = [noise_from_residual(fit.residual_px.rms, fit.m_ref.shape[0]) for fit in fitted.fits]
    gains = [suggest_gains(fit.condition.percentiles["p50"], n, fit.m_ref, fit.normal, route.camera.mean_focal).gains
             for fit, n in zip(fitted.fits, noise)]
    controller = AdaptiveTrackingController(ControllerGains(), dhat0=DHAT0_FACTOR * depths[0])
    switches = switch_times(fitted, times)
    start = compose_planar_pose(route.start_pose, parse_offset(DEFAULT_OFFSET))
    camera, steps = run_route(route, fitted, switches, controller, start, DT, float(times[-1]) + DT,
                              ActuatorLimits(max_v=DEFAULT_MAX_V, max_w=DEFAULT_MAX_W), pixel_noise, seed + 1000, gains,
                              [n / route.camera.mean_focal for n in noise])
    records = list(steps)
    t = np.array([r.t for r in records])
    pose = np.array([r.pose for r in records])
    taught = route.profile.poses_at(t, route.start_pose)
    error = np.linalg.norm(pose[:, :2] - taught[:, :2], axis=1)
    in_force = np.searchsorted(switches, t, side="right")
    dhat = np.array([r.dhat for r in records])
    ends = [np.flatnonzero(in_force == k)[-1] for k in range(len(depths))]
    # Each switch's step from the frame before: the law's e1, e3, ebar2 (V's (36) terms), then v_c, w_c.
    steps = [[abs(getattr(b.output.errors, n) - getattr(a.output.errors, n)) for n in ("e1", "e3", "ebar2")]
             + [abs(b.v_c - a.v_c), abs(b.w_c - a.w_c)] if a.output is not None and b.output is not None else [np.nan] * 5
             for a, b in (records[k - 1:k + 1] for k in np.searchsorted(t, switches - 1e-9))]
    return {
        "t": t, "error": error, "switches": switches, "dhat_over_d": dhat / depths[in_force],
        "end_cm": 100.0 * error[-1], "end_deg": abs(float(np.degrees(wrap_angle(pose[-1, 2] - taught[-1, 2])))),
        "along_cm": 100.0 * error[t >= SETTLED_S].max(), "switch_steps": np.array(steps),
        "at_switch_cm": [100.0 * error[np.abs(t - s) <= AROUND_SWITCH_S].max() for s in switches],
        "depth_error": [dhat[k] / depths[i] - 1.0 for i, k in enumerate(ends)],
        "rho_error": [tr.depth_ratio / (b / a) - 1.0 for tr, a, b in zip(fitted.transitions, depths, depths[1:])],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plot", help="write the figure here (PNG)")
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    exact = corridor_run(0.0, 0.0, 0)
    noisy = [corridor_run(TEACH_NOISE_PX, REPEAT_NOISE_PX, seed) for seed in range(args.seeds)]
    print(f"| case | end (cm / deg) | max error after {SETTLED_S:g} s (cm) | max error within 1 s of switch 1, 2, 3 (cm) "
          "| dhat / d*_i - 1 at the end of segments 0-3 (%) | rho error 1-3 (%) |")
    print("|---|---|---|---|---|---|")
    for name, run in [("exact", exact)] + [(f"noisy, seed {seed}", run) for seed, run in enumerate(noisy)]:
        print(f"| {name} | {run['end_cm']:.2f} / {run['end_deg']:.3f} | {run['along_cm']:.1f} | {', '.join(f'{v:.1f}' for v in run['at_switch_cm'])} | "
              f"{', '.join(f'{100 * v:+.1f}' for v in run['depth_error'])} | {', '.join(f'{100 * v:+.1f}' for v in run['rho_error'])} |")
    converged = sum(run["end_cm"] < 2.0 and run["end_deg"] < 0.5 for run in noisy)
    print(f"\n{TEACH_NOISE_PX} px taught, {REPEAT_NOISE_PX} px repeat: {converged} of {len(noisy)} end within 2 cm and 0.5 deg")
    for name, runs in (("exact", [exact]), ("noisy", noisy)):
        worst = np.nanmax([run["switch_steps"] for run in runs], axis=(0, 1))
        print(f"{name}: largest step at a switch of e1 {worst[0]:.1e}, e3 {worst[1]:.1e} rad, ebar2 {worst[2]:.1e}, "
              f"v_c {worst[3]:.4f} m/s, w_c {worst[4]:.4f} rad/s; frames without the law's output there: "
              f"{sum(int(np.isnan(run['switch_steps'][:, 0]).sum()) for run in runs)}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        figure, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
        top.semilogy(exact["t"], np.maximum(exact["error"], 1e-5), label="exact measurements")
        top.semilogy(noisy[0]["t"], noisy[0]["error"], label=f"{REPEAT_NOISE_PX} px, seed 0", alpha=0.8)
        bottom.plot(exact["t"], exact["dhat_over_d"], label="exact measurements")
        bottom.plot(noisy[0]["t"], noisy[0]["dhat_over_d"], label=f"{REPEAT_NOISE_PX} px, seed 0", alpha=0.8)
        for axis in (top, bottom):
            for switch in exact["switches"]:
                axis.axvline(switch, color="gray", linestyle=":")
            axis.legend(loc="upper right")
        top.set_ylabel("position error (m)")
        bottom.set_ylabel("dhat / d*_i (segment in force)")
        bottom.set_xlabel("t (s); dotted: the switches")
        top.set_title("The corridor route (23 m, 4 targets) in closed loop")
        figure.tight_layout()
        figure.savefig(args.plot, dpi=120)


if __name__ == "__main__":
    main()
