"""A Kalman filter on (theta, x_h1, x_h2) and the inverse depth rho = 1/d*, between the
camera and the law: the lateral gain k_2 would multiply a real detector's noise into the
commands. Its prediction (an arc), correction, learnt noise and gates: docs/method.md,
"State filter".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Collection

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidValueError
from .controller import Measurement
from .depth import check_depth
from .frames import wrap_angle
from .known_normal import normal_equations, point_jacobian
from .labels import Label


#: chi^2 with 3 degrees of freedom at 99.9 %: an innovation farther than this is an outlier.
CHI2_3DOF_999 = 16.266

class FilterOutcome(Label):
    """What the state filter did with a frame (run files' ``filter``)."""

    FUSED = "fused"
    #: Rejected as an outlier.
    GATED = "gated"
    #: (Re)started from the frame's measurement.
    STARTED = "started"
    #: No frame: the estimate is a prediction.
    PREDICTED = "predicted"


@dataclass(frozen=True)
class FilterSettings:
    """Tuning of :class:`ServoStateFilter` (docs/method.md, "State filter" and "The depth in the
    filter"), field by field: the velocity errors' spectral densities (m/s/sqrt(Hz),
    rad/s/sqrt(Hz)); the depth's prior and trust (relative stds), pull rate (1/s), settled
    lateral error (rad) and met gap (relative) of :func:`scheduled_depth_pull`; the innovation
    gate (squared Mahalanobis distance) and rejections in a row before a restart; the noise's
    time constant (s) and floor (normalised units); the residual's chi^2 quantile gate; the
    stds (rad, units of d*) within which the law acts on a prediction; the settle and fade
    times (s) before and while the law's feedback fades in from the taught commands (25),
    shrinking with the noise below ``settle_noise``."""

    speed_noise: float = 0.0005
    turn_noise: float = 0.00015
    depth_prior: float = 1.0
    depth_trust: float = 0.05
    depth_pull_rate: float = 1.0
    lateral_settled: float = math.radians(0.3)
    depth_met: float = 0.05
    gate: float = CHI2_3DOF_999
    reset_after: int = 5
    noise_time_constant: float = 0.5
    min_noise: float = 1e-4
    residual_quantile: float = 0.999
    coast_theta_std: float = math.radians(0.5)
    coast_x_h_std: float = 0.005
    settle_time: float = 1.0
    fade_time: float = 2.0
    settle_noise: float = 4e-4


@dataclass(frozen=True)
class FilterEstimate:
    """The filter's estimate at one instant: ``measurement`` (theta, x_h1, x_h2) the law acts
    on, their ``std`` (3,), the detector's ``noise`` (normalised units), the last frame's
    ``outcome``, the ``depth`` 1/rho (m) and ``depth_pull`` (1/s, :meth:`~ServoStateFilter.depth_pull`)."""

    measurement: Measurement
    std: NDArray[np.float64]
    noise: float
    outcome: FilterOutcome
    depth: float = math.nan
    depth_pull: float = 0.0


def scheduled_depth_pull(pull: float, ebar2: float, e3: float, k_2: float, settings: FilterSettings,
                         met: bool = True) -> float:
    """The rate kappa (1/s) of the pull in ``dhat_dot = (31) + kappa (d_f - dhat)`` towards
    the filter's depth d_f.

    Until dhat has ``met`` d_f, ``kappa = pull``; after, ``pull / (1 + (l / lateral_settled)^2)``
    with ``l = sqrt(k_2 ebar2^2 + e3^2)``, the lateral part of V (36): while the robot turns onto
    its path (31) moves dhat away and back, and a stiff pull would slow that. Any kappa >= 0 adds
    ``-(kappa / gamma_1) d~^2`` to V_dot (38) when d_f = d* (docs/method.md).
    """
    lateral0 = settings.lateral_settled
    if pull <= 0.0 or not met or lateral0 <= 0.0:
        return max(pull, 0.0)
    return pull / (1.0 + (k_2 * ebar2 * ebar2 + e3 * e3) / (lateral0 * lateral0))


def _arc(v: float, w: float, dt: float) -> tuple[float, float, float, float]:
    """Displacement (dx, dy) of a unicycle holding (v, w) for dt, in its start frame (21),
    and the cosine and sine of its turn ``w dt``."""
    dphi = w * dt
    c, s = math.cos(dphi), math.sin(dphi)
    if abs(dphi) < 1e-6:
        # Second-order series of sin(dphi)/w and (1 - cos(dphi))/w.
        return v * dt * (1.0 - dphi * dphi / 6.0), 0.5 * v * dt * dphi, c, s
    return v * s / w, v * (1.0 - c) / w, c, s


def measurement_information(m_ref: NDArray[np.float64], normal: NDArray[np.float64], state: ArrayLike) -> NDArray[np.float64]:
    """``J^T J`` (3, 3) of the N normalised image points (:func:`~.known_normal.point_jacobian`)
    with respect to (theta, x_h1, x_h2): over the noise variance, a frame's information."""
    theta, x1, x2 = (float(s) for s in state)
    g = m_ref @ normal
    _, _, _, jy_t, jy_1, jy_2, jz_t, jz_1 = point_jacobian(math.cos(theta), math.sin(theta), m_ref[:, 1], m_ref[:, 2], g, x1, x2)
    jacobian = np.concatenate([
        np.stack([jy_t, jy_1, jy_2], axis=1),
        np.stack([jz_t, jz_1, np.zeros_like(g)], axis=1),
    ])
    return jacobian.T @ jacobian


# Plain floats: numpy's per-call overhead would dominate a 4-state update every period. A
# symmetric 3x3 is the 6-tuple of its upper triangle, the 4x4 covariance of (theta, x_h1,
# x_h2, rho) the 10-tuple (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33).
Sym3 = tuple[float, float, float, float, float, float]
Sym4 = tuple[float, float, float, float, float, float, float, float, float, float]
Vec3 = tuple[float, float, float]
State = tuple[float, float, float, float]


def _sym_inverse(a: Sym3) -> Sym3:
    """Inverse of a symmetric 3x3 (cofactors); ZeroDivisionError when singular."""
    a00, a01, a02, a11, a12, a22 = a
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    det = a00 * c00 + a01 * c01 + a02 * c02
    if not det > 0.0:
        raise ZeroDivisionError("not positive definite")
    inv = 1.0 / det
    return (c00 * inv, c01 * inv, c02 * inv, (a00 * a22 - a02 * a02) * inv, (a01 * a02 - a00 * a12) * inv,
            (a00 * a11 - a01 * a01) * inv)


def _sym_times(s: Sym3, a0: float, a1: float, a2: float) -> Vec3:
    """The symmetric 3x3 ``s`` times the vector (a0, a1, a2)."""
    s00, s01, s02, s11, s12, s22 = s
    return s00 * a0 + s01 * a1 + s02 * a2, s01 * a0 + s11 * a1 + s12 * a2, s02 * a0 + s12 * a1 + s22 * a2


def residual_to_variance(points: int) -> float:
    """``sigma^2 / r^2`` for the RMS residual r of a known-normal solve of N ``points``: three
    parameters fitted to 2N coordinates."""
    return 2.0 * points / max(2.0 * points - 3.0, 1.0)


#: The inverse depth stays within this factor of its prior: 1/rho finite after a wild frame.
INVERSE_DEPTH_RANGE = 100.0


class ServoStateFilter:
    """Extended Kalman filter on (theta, x_h1, x_h2, 1/d*) (module docstring).

    ``m_ref`` (N, 3): m*_i; ``normal`` (3,): n* in F*; ``noise``: the detector's initial
    per-coordinate noise (normalised units), refined by the residuals; ``depth``: dhat(0) (m),
    or later by :meth:`expect_depth`.
    """

    def __init__(self, m_ref: ArrayLike, normal: ArrayLike, noise: float, depth: float | None = None) -> None:
        m_ref = np.asarray(m_ref, dtype=float)
        self.settings = FilterSettings()
        if not (math.isfinite(noise) and noise >= 0.0):
            raise InvalidValueError(f"the initial measurement noise must be a non-negative number, got {noise}")
        points = m_ref.shape[0]
        self._y_ref = m_ref[:, 1].tolist()
        self._z_ref = m_ref[:, 2].tolist()
        self._g = (m_ref @ np.asarray(normal, dtype=float)).tolist()
        self._residual_to_variance = residual_to_variance(points)
        from scipy.stats import chi2

        dof = max(2 * points - 3, 1)
        self._residual_gate = float(chi2.ppf(self.settings.residual_quantile, dof)) / dof
        self.noise_variance = max(noise, self.settings.min_noise) ** 2
        self._state: State | None = None
        self._covariance: Sym4 | None = None
        self._rho_prior = math.nan
        if depth is not None:
            self.expect_depth(depth)
        self.rejected_in_a_row = 0
        self.last_outcome = FilterOutcome.PREDICTED
        self.fused_time = 0.0
        #: Set by :meth:`take_over` until the next frame is fused.
        self.carried_std: NDArray[np.float64] | None = None

    def expect_depth(self, depth: float) -> None:
        """Start the inverse depth at ``1 / depth`` (m), before the first frame (or at :meth:`take_over`)."""
        self._rho_prior = 1.0 / check_depth(depth, "the filter's depth guess")

    @property
    def state(self) -> NDArray[np.float64] | None:
        """(theta, x_h1, x_h2) at the time of the last fused frame, or None before the first."""
        return None if self._state is None else np.array(self._state[:3])

    @property
    def full_state(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """(theta, x_h1, x_h2, 1/d*) and its covariance (4, 4), or None before the first frame."""
        if self._state is None:
            return None
        covariance = np.zeros((4, 4))
        covariance[np.triu_indices(4)] = self._covariance
        return np.array(self._state), covariance + np.triu(covariance, 1).T

    def take_over(self, state: ArrayLike, covariance: ArrayLike, before: ServoStateFilter, motion_std: ArrayLike) -> None:
        """Go on from filter ``before``'s :attr:`full_state`, ``state`` and ``covariance`` once
        expressed against this one's F* (a route's switch, :meth:`~.route.Transition.carried_state`),
        with its fused time and, if larger, the noise it learnt (the same camera's): no
        restart from a frame, so the estimate and the law's feedback stay continuous. Until
        a frame is fused, :meth:`trusted` judges the prediction by ``motion_std`` (3,), the
        stds without the transition's own uncertainty: the law's error is made continuous
        across the switch, so the new reference's offset does not make it less safe to act on."""
        self.carried_std = np.asarray(motion_std, dtype=float)
        self.expect_depth(1.0 / float(state[3]))
        self._state = tuple(float(value) for value in state)
        self._covariance = tuple(float(value) for value in np.asarray(covariance, dtype=float)[np.triu_indices(4)])
        self.fused_time = before.fused_time
        self.noise_variance = max(self.noise_variance, before.noise_variance)

    def trusted(self, estimate: FilterEstimate | None) -> bool:
        """Whether a prediction is good enough to act on without a frame."""
        if estimate is None or not self.settled:
            return False
        std = estimate.std if self.carried_std is None else self.carried_std
        return bool(std[0] <= self.settings.coast_theta_std and max(std[1], std[2]) <= self.settings.coast_x_h_std)

    @property
    def settling_fraction(self) -> float:
        """How far the law's feedback is faded in, 0 to 1 (see ``FilterSettings``)."""
        settle, fade = self._settle_times()
        if self.fused_time < settle:
            return 0.0
        return 1.0 if fade <= 0.0 else min(1.0, (self.fused_time - settle) / fade)

    @property
    def settled(self) -> bool:
        """True once the filter has fused its settle and fade times of frames."""
        return self._state is not None and self.fused_time >= sum(self._settle_times()) - 1e-9

    def _settle_times(self) -> tuple[float, float]:
        """Settle and fade times, shrunk by (noise / settle_noise)^2: the frames needed to
        average the noise down."""
        scale = min(1.0, self.noise_variance / self.settings.settle_noise**2) if self.settings.settle_noise > 0 else 1.0
        return self.settings.settle_time * scale, self.settings.fade_time * scale

    def predict(self, v: float, w: float, dt: float) -> None:
        """Advance the estimate over a command (v, w) held for dt."""
        if self._state is None:
            return
        self._state, self._covariance = self._predicted(self._state, self._covariance, v, w, dt)

    def _predicted(self, state: State, covariance: Sym4, v: float, w: float, dt: float) -> tuple[State, Sym4]:
        """(5), (23) over one held command, and ``F P F^T + Q`` with the Jacobian
        ``F = [[1, 0, 0, 0], [0, c, s, f13], [0, -s, c, f23], [0, 0, 0, 1]]``, where
        ``(f13, f23) = -Rz(-w dt) [dx, dy]`` is how the step's x_h moves with rho."""
        settings = self.settings
        theta, x1, x2, rho = state
        dx, dy, c, s = _arc(v, w, dt)
        a, b = x1 - dx * rho, x2 - dy * rho
        f13, f23 = -(c * dx + s * dy), s * dx - c * dy
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = covariance
        # Rows 1 and 2 of F P (row 0 and 3 are P's own).
        m10 = c * p01 + s * p02 + f13 * p03
        m11 = c * p11 + s * p12 + f13 * p13
        m12 = c * p12 + s * p22 + f13 * p23
        m13 = c * p13 + s * p23 + f13 * p33
        m21 = -s * p11 + c * p12 + f23 * p13
        m22 = -s * p12 + c * p22 + f23 * p23
        m23 = -s * p13 + c * p23 + f23 * p33
        # White velocity errors of spectral density q enter through g_v = [0, -rho, 0, 0]
        # and g_w = [-1, x_h2, -x_h1, 0]; their integral over dt has variance q dt.
        qv = settings.speed_noise**2 * dt * rho * rho
        qw = settings.turn_noise**2 * dt
        return (theta - w * dt, c * a + s * b, -s * a + c * b, rho), (
            p00 + qw,
            m10 - qw * x2,
            -s * p01 + c * p02 + f23 * p03 + qw * x1,
            p03,
            c * m11 + s * m12 + f13 * m13 + qv + qw * x2 * x2,
            -s * m11 + c * m12 + f23 * m13 - qw * x1 * x2,
            m13,
            -s * m21 + c * m22 + f23 * m23 + qw * x1 * x1,
            m23,
            p33,
        )

    def correct(self, measured: Measurement, residual: float, dt: float) -> FilterOutcome:
        """Fuse a frame's known-normal solution and its RMS ``residual`` (normalised units),
        ``dt`` (s) after the previous frame; returns FUSED, GATED or STARTED."""
        if math.isfinite(residual) and self._state is not None:
            # The residual alone tells a wrong point: r^2 2N / sigma^2 ~ chi^2(2N - 3).
            sample = residual * residual * self._residual_to_variance
            if sample / self.noise_variance > self._residual_gate:
                return self._reject(measured, residual, dt)
            # Learnt before the innovation gate: a noisier camera must not look like outliers.
            weight = min(1.0, dt / self.settings.noise_time_constant) if self.settings.noise_time_constant > 0 else 1.0
            self.noise_variance += weight * (sample - self.noise_variance)
            self.noise_variance = max(self.noise_variance, self.settings.min_noise**2)
        observed = self._observed(measured)
        if observed is None:
            return self._gated()
        z, inverse_information = observed
        r00, r01, r02, r11, r12, r22 = (self.noise_variance * value for value in inverse_information)
        if self._state is None:
            return self._start(z, (r00, r01, r02, r11, r12, r22), residual, dt)
        theta, x1, x2, rho = self._state
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._covariance
        innovation = (wrap_angle(z[0] - theta), z[1] - x1, z[2] - x2)
        try:
            inverse = _sym_inverse((p00 + r00, p01 + r01, p02 + r02, p11 + r11, p12 + r12, p22 + r22))
        except ZeroDivisionError:
            return self._reject(measured, residual, dt, observed)
        # S^-1 nu, and the squared Mahalanobis distance nu^T S^-1 nu.
        weights = _sym_times(inverse, *innovation)
        if innovation[0] * weights[0] + innovation[1] * weights[1] + innovation[2] * weights[2] > self.settings.gate:
            return self._reject(measured, residual, dt, observed)
        self.rejected_in_a_row = 0
        # The measurement sees the first three states: K = P[:, :3] S^-1, x += K nu and
        # P -= P[:, :3] S^-1 P[:3, :]. Column j of P[:3, :] is (p0j, p1j, p2j); u_j = S^-1 of it.
        # Written out (a step of the closed loop pays for every Python call): the same products and sums.
        w0, w1, w2 = weights
        a0, a1, a2 = _sym_times(inverse, p00, p01, p02)
        b0, b1, b2 = _sym_times(inverse, p01, p11, p12)
        c0, c1, c2 = _sym_times(inverse, p02, p12, p22)
        d0, d1, d2 = _sym_times(inverse, p03, p13, p23)
        low, high = self._rho_prior / INVERSE_DEPTH_RANGE, self._rho_prior * INVERSE_DEPTH_RANGE
        self._state = (theta + p00 * w0 + p01 * w1 + p02 * w2, x1 + p01 * w0 + p11 * w1 + p12 * w2,
                       x2 + p02 * w0 + p12 * w1 + p22 * w2, min(max(rho + p03 * w0 + p13 * w1 + p23 * w2, low), high))
        self._covariance = (
            p00 - (p00 * a0 + p01 * a1 + p02 * a2), p01 - (p00 * b0 + p01 * b1 + p02 * b2),
            p02 - (p00 * c0 + p01 * c1 + p02 * c2), p03 - (p00 * d0 + p01 * d1 + p02 * d2),
            p11 - (p01 * b0 + p11 * b1 + p12 * b2), p12 - (p01 * c0 + p11 * c1 + p12 * c2),
            p13 - (p01 * d0 + p11 * d1 + p12 * d2), p22 - (p02 * c0 + p12 * c1 + p22 * c2),
            p23 - (p02 * d0 + p12 * d1 + p22 * d2), p33 - (p03 * d0 + p13 * d1 + p23 * d2),
        )
        self.fused_time += dt
        self.carried_std = None
        self.last_outcome = FilterOutcome.FUSED
        return FilterOutcome.FUSED

    def _observed(self, measured: Measurement) -> tuple[Vec3, Sym3] | None:
        """The measurement as a state, and the inverse of its points' information (per unit
        noise variance); None when the points do not determine the state."""
        z = (float(measured.theta), float(measured.x_h1), float(measured.x_h2))
        # measurement_information in plain floats, as a symmetric 6-tuple.
        information = normal_equations(math.cos(z[0]), math.sin(z[0]), self._y_ref, self._z_ref, self._g, z[1], z[2])[0]
        try:
            return z, _sym_inverse(information)
        except ZeroDivisionError:
            return None

    def _reject(self, measured: Measurement, residual: float, dt: float,
                observed: tuple[Vec3, Sym3] | None = None) -> FilterOutcome:
        """An outlier; after ``reset_after`` in a row the filter restarts from this frame
        (``observed``: :meth:`_observed` of it, when already computed)."""
        self.rejected_in_a_row += 1
        if self.rejected_in_a_row >= self.settings.reset_after:
            # The camera, not the detector, changed (or the filter diverged): start over.
            if math.isfinite(residual):
                self.noise_variance = max(residual * residual * self._residual_to_variance, self.settings.min_noise**2)
            observed = observed or self._observed(measured)
            if observed is not None:
                z, inverse_information = observed
                return self._start(z, tuple(self.noise_variance * value for value in inverse_information), residual, dt)
        return self._gated()

    def _gated(self) -> FilterOutcome:
        self.last_outcome = FilterOutcome.GATED
        return FilterOutcome.GATED

    def _start(self, z: Vec3, covariance: Sym3, residual: float, dt: float) -> FilterOutcome:
        if self._state is None and math.isfinite(residual):
            # The first frame's own residual beats a prior from the (maybe cleaner) taught images.
            sample = residual * residual * self._residual_to_variance
            if sample > self.noise_variance:
                covariance = tuple(value * (sample / self.noise_variance) for value in covariance)
                self.noise_variance = sample
        # A restart keeps the time already fused (the law's feedback and (31) stay on) and
        # what the motion has measured of the depth: only the pose starts over.
        restarted = self._state is not None
        if restarted:
            rho, rho_variance = self._state[3], self._covariance[9]
        else:
            if not math.isfinite(self._rho_prior):
                raise InvalidValueError("the state filter needs a depth guess before its first frame (expect_depth)")
            rho, rho_variance = self._rho_prior, (self.settings.depth_prior * self._rho_prior) ** 2
        c00, c01, c02, c11, c12, c22 = covariance
        self._state = (z[0], z[1], z[2], rho)
        self._covariance = (c00, c01, c02, 0.0, c11, c12, 0.0, c22, 0.0, rho_variance)
        self.rejected_in_a_row = 0
        self.fused_time = self.fused_time + dt if restarted else dt
        self.last_outcome = FilterOutcome.STARTED
        self.carried_std = None
        return FilterOutcome.STARTED

    def depth_pull(self) -> float:
        """The rate (1/s) at which the update law may pull dhat towards the filter's depth:
        ``depth_pull_rate / (1 + (relative std / depth_trust)^2)``."""
        if self._state is None or self.settings.depth_pull_rate <= 0.0:
            return 0.0
        rho = self._state[3]
        relative = math.sqrt(max(self._covariance[9], 0.0)) / rho
        trust = self.settings.depth_trust
        return self.settings.depth_pull_rate / (1.0 + (relative / trust) ** 2) if trust > 0.0 else 0.0

    def estimate(self, commands: Collection[tuple[float, float]], dt: float) -> FilterEstimate | None:
        """The estimate carried over the ``commands`` sent since the last frame was taken
        (latency); None before the first frame."""
        if self._state is None:
            return None
        state, p = self._state, self._covariance
        for v, w in commands:
            state, p = self._predicted(state, p, v, w, dt)
        theta, x1, x2, rho = state
        return FilterEstimate(
            measurement=Measurement(theta=theta, x_h1=x1, x_h2=x2),
            std=np.array((math.sqrt(max(p[0], 0.0)), math.sqrt(max(p[4], 0.0)), math.sqrt(max(p[7], 0.0)))),
            noise=math.sqrt(self.noise_variance),
            outcome=self.last_outcome,
            depth=1.0 / rho,
            depth_pull=self.depth_pull(),
        )
