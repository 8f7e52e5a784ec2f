"""Shared fixtures and generators for the hbvs test suite."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "samples"

# Tests never need a display; matplotlib must not look for one.
os.environ.setdefault("MPLBACKEND", "Agg")


def random_planar_scene(rng: np.random.Generator, n_points: int, n_frames: int, tilted: bool):
    """A random target plane seen from F* and from ``n_frames`` random planar poses.

    Returns a dict with the reference points ``m_ref`` (N, 3), the current points ``m``
    (F, N, 3), the true normal, d*, theta (F,), x_h (F, 2), the Euclidean points in F*
    and the true H (F, 3, 3). Scenes with a point near the camera's height or behind a
    camera are redrawn.
    """
    from hbvs_cli.core.frames import rotation_z

    while True:
        nz = rng.normal(0.0, 0.3) if tilted else 0.0
        normal = np.array([1.0, rng.normal(0.0, 0.4), nz])
        normal /= np.linalg.norm(normal)
        d_star = rng.uniform(3.0, 6.0)
        u = np.cross(normal, [0.0, 0.0, 1.0])
        u /= np.linalg.norm(u)
        v = np.cross(normal, u)
        a = rng.uniform(-1.0, 1.0, (n_points, 1))
        b = rng.uniform(0.2, 1.0, (n_points, 1)) * rng.choice([-1.0, 1.0], (n_points, 1))
        points = d_star * normal + a * u + b * v
        m_ref = points / points[:, :1]
        if np.any(np.abs(m_ref[:, 2]) < 0.02) or np.linalg.svd(m_ref, compute_uv=False)[-1] < 0.02:
            continue
        theta = rng.normal(0.0, 0.3, n_frames)
        x_h = rng.normal(0.0, 0.3, (n_frames, 3))
        x_h[:, 2] = 0.0
        m_bar = (d_star * x_h)[:, None, :] + np.einsum("fij,nj->fni", rotation_z(theta), points)
        if np.any(m_bar[..., 0] <= 0.5):
            continue
        return {
            "m_ref": m_ref,
            "m": m_bar / m_bar[..., :1],
            "m_bar": m_bar,
            "points_ref": points,
            "normal": normal,
            "d_star": d_star,
            "theta": theta,
            "x_h": x_h[:, :2],
            "H": rotation_z(theta) + x_h[:, :, None] * normal[None, None, :],
        }


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20031027)


def run_hbvs(*args: str, input: bytes | None = None, check: bool = False, timeout: float = 600, env: dict | None = None):
    """Run the installed ``hbvs`` entry point as a user would (``python -m hbvs_cli``)."""
    import subprocess

    full_env = dict(os.environ)
    full_env.setdefault("MPLBACKEND", "Agg")
    if env:
        full_env.update(env)
    return subprocess.run(
        [sys.executable, "-m", "hbvs_cli", *args],
        input=input,
        capture_output=True,
        check=check,
        timeout=timeout,
        env=full_env,
    )
