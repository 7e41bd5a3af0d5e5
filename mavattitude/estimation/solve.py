"""The per-sample solver: IGN (Section 4, steps 1–7), CGN, maximum likelihood and TRIAD.

Plain Python floats throughout (numpy's per-call overhead would dominate a two-vector problem); the
equations are those of :mod:`.kernel`, shared with the vectorised :mod:`.batch`.

Steps of the paper's IGN: (1) start from TRIAD (see below for a warm start); (2) normalise the vectors
(Eq. 3–4); (3) weights from Eq. 9/21; (4)–(7) iterate Eq. 34–35, at most ``max_iterations`` times,
until the estimated error left is at most ``tolerance`` (:func:`.kernel.converged`).

From TRIAD, Eq. 34 converges in 2 corrections over random attitudes (at most 4 in the maneuvering
flight of tools/reproduce_paper.py): TRIAD fits the heavily weighted accelerometer exactly, and
Gauss–Newton's linear rate on what is left is tiny. When the two vectors disagree badly (a magnetic
disturbance) that rate is not tiny, and once it shows (:func:`.kernel.slow`) the remaining corrections
are Newton's, to the same optimum (:func:`.kernel.scalar_weight_step`).

A warm start ``q0`` (the previous sample's answer) is used only when its Wahba loss is not above
TRIAD's (a stale or flipped one may sit at a stationary point of Eq. 34 180° away, docs/paper-notes.md), and only
for ``WARM_START_BUDGET`` corrections: in a maneuver the previous answer's tilt error shrinks at
Gauss–Newton's slow linear rate (0.15 per step in tools/reproduce_paper.py's flight), so the solver
then restarts from TRIAD. All corrections count in ``iterations``.
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import DegenerateGeometryError, InputError
from . import kernel
from .conventions import ACC_REF_NED, quat_from_rotation_parts
from .noise import NoiseModel

DEFAULT_METHOD = "ign"  # the paper's improved Gauss–Newton
MAX_ITERATIONS = 10
TOLERANCE_RAD = 1e-12
MIN_ANGLE_DEG = 5.0
WARM_START_BUDGET = 2  # corrections tried from a warm start before restarting from TRIAD


@dataclass(eq=False, slots=True)
class SolveResult:
    """One attitude solution. ``loss`` and ``covariance`` are computed on first access."""

    q: NDArray[np.float64]  # [w, x, y, z], body FRD → NED, w ≥ 0
    iterations: int  # Gauss–Newton corrections applied (0 for "triad")
    converged: bool
    method: str
    noise: NoiseModel = field(repr=False)
    _units: tuple = field(repr=False)  # (ŵ_mag, v̂_mag, ŵ_acc, v̂_acc): the measured and reference directions
    _norms: tuple[float, float] = field(repr=False)  # (|acc|, |mag|)
    _obs: tuple | None = field(default=None, repr=False)  # the solver's ((ŵ₁, v₁, weight₁), (ŵ₂, v₂, weight₂))
    _loss: float | None = field(default=None, repr=False)
    _covariance: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def loss(self) -> float:
        """Wahba loss (Eq. 11) at ``q`` with the method's weights (the paper's for "triad")."""
        if self._loss is None:
            if self._obs is None:
                self._obs = observations(self.method, self.noise, self._units, self._norms)
            self._loss = float(kernel.wahba_loss(tuple(self.q), self._obs, kernel.RULES[self.method].matrix_weights))
        return self._loss

    @property
    def covariance(self) -> NDArray[np.float64]:
        """Predicted error-angle covariance (rad², body): sandwich (ign, cgn), CRB (ml), linearised TRIAD."""
        if self._covariance is None:
            w_mag, _, w_acc, _ = self._units
            n_acc, n_mag = self._norms
            sym = kernel.covariance(
                self.method, (w_mag, n_mag, self.noise.mag_var), (w_acc, n_acc, self.noise.accel_var)
            )
            # checked and built on the floats: numpy's isfinite and a nested-tuple array cost 4 µs of the ~20
            # that every ATTITUDE_QUATERNION_COV of the service pays here
            if not all(map(math.isfinite, sym)):  # a singular information matrix (kernel.sym_inverse)
                raise DegenerateGeometryError("no covariance: " + SINGULAR_MESSAGE)
            xx, xy, xz, yy, yz, zz = sym
            self._covariance = np.array((xx, xy, xz, xy, yy, yz, xz, yz, zz)).reshape(3, 3)
        return self._covariance


def covariances(results: list[SolveResult]) -> NDArray[np.float64]:
    """``[r.covariance for r in results]`` as ``(N, 3, 3)``, NaN where a result has none (a singular
    information matrix): the kernel once on arrays per method and noise model. Its arithmetic is elementwise
    (``+ − × /`` only), so the values are those of the one-by-one path, bit for bit."""
    out = np.full((len(results), 3, 3), np.nan)
    groups: dict[tuple[str, NoiseModel], list[int]] = {}
    for i, r in enumerate(results):
        groups.setdefault((r.method, r.noise), []).append(i)
    for (method, noise), rows in groups.items():
        w_mag, w_acc = (np.array([results[i]._units[k] for i in rows], dtype=float).T for k in (0, 2))
        n_acc, n_mag = np.array([results[i]._norms for i in rows], dtype=float).T
        with np.errstate(all="ignore"):  # a singular matrix gives NaN (kernel.sym_inverse), as one by one
            xx, xy, xz, yy, yz, zz = kernel.covariance(
                method, (tuple(w_mag), n_mag, noise.mag_var), (tuple(w_acc), n_acc, noise.accel_var)
            )
        cov = np.stack([xx, xy, xz, xy, yy, yz, xz, yz, zz], -1).reshape(-1, 3, 3)
        cov[~np.isfinite(cov).all(axis=(1, 2))] = np.nan
        out[rows] = cov
    return out


def observations(method: str, noise: NoiseModel, units: tuple, norms: tuple, weights: tuple | None = None) -> tuple:
    """The solver's observations (:func:`.kernel.observations`) from ``(ŵ_mag, v̂_mag, ŵ_acc, v̂_acc)`` and
    ``(|acc|, |mag|)``, with the paper's weights ``(a_mag, a_acc)`` (Eq. 9, 21) when not given; floats or arrays."""
    (w_mag, v_mag, w_acc, v_acc), (n_acc, n_mag) = units, norms
    a_mag, a_acc = weights or (
        kernel.paper_weight(w_mag, n_mag, noise.mag_var),
        kernel.paper_weight(w_acc, n_acc, noise.accel_var),
    )
    return kernel.observations(
        method, (w_mag, n_mag, v_mag, noise.mag_var, a_mag), (w_acc, n_acc, v_acc, noise.accel_var, a_acc)
    )


def check_method(method: str) -> None:
    if method not in kernel.RULES:
        raise InputError(f"unknown method {method!r}; choose one of {', '.join(kernel.RULES)}")


@functools.lru_cache(maxsize=16)
def check_settings(max_iterations: int, tolerance: float, min_angle_deg: float) -> float:
    """Validate the iteration bounds; return ``sin(min_angle)``, the collinearity threshold."""
    if not (isinstance(max_iterations, numbers.Integral) and max_iterations >= 1):
        raise InputError(f"max_iterations must be an integer ≥ 1, got {max_iterations!r}")
    if not (math.isfinite(tolerance) and tolerance > 0.0):
        raise InputError(f"tolerance must be a finite angle > 0 rad, got {tolerance!r}")
    if not (0.0 < min_angle_deg < 90.0):
        raise InputError(f"min_angle_deg must be in (0, 90) degrees, got {min_angle_deg!r}")
    return math.sin(math.radians(min_angle_deg))


def geometry_message(what: str, sin_angle: float, min_angle_deg: float) -> str:
    angle = math.degrees(math.asin(min(max(sin_angle, 0.0), 1.0)))
    return (
        f"{what} are {angle:.2f}° from collinear (minimum {min_angle_deg:g}°): "
        "the rotation about their common direction is unobservable"
    )


SINGULAR_MESSAGE = (
    "the solver's normal matrix is singular: acc and mag (or their references) are collinear in floating "
    "point for their weights, so the rotation about their common direction is unobservable"
)


def weights_message(a_mag: float, a_acc: float) -> str:
    """Why :func:`.kernel.weights_usable` refused a pair: relative unit-vector noise of each vector."""
    rel_acc, rel_mag = (_relative_noise(a) for a in (a_acc, a_mag))
    return (
        f"unusable noise-to-signal: σ/|vector| ≈ {rel_acc:.1e} for acc and {rel_mag:.1e} for mag; each must be "
        f"between 1e-10 and 1, and within 1e4 of the other (a vector buried in its noise, or a σ that is not "
        f"in its measurement's units)"
    )


def _relative_noise(a: float) -> float:
    """``κ = √(tr R_unit / 3) = a^(−½)``: a per-axis σ/|Ŵ|."""
    return (1.0 / a) ** 0.5 if 0.0 < a < math.inf else (math.inf if a == 0.0 else 0.0)


def _unit(name: str, v: ArrayLike) -> tuple[tuple[float, float, float], float]:
    """``(ŵ, |Ŵ|)`` of a 3-vector given as an array or a sequence (Eq. 3–4)."""
    try:
        x, y, z = v.tolist() if type(v) is np.ndarray else v  # type: ignore[union-attr]
        x, y, z = float(x), float(y), float(z)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a 3-vector of numbers, got {v!r}") from None
    n = (x * x + y * y + z * z) ** 0.5
    if not 0.0 < n < math.inf:  # also false for NaN
        raise InputError(f"{name} must be finite and non-zero, got {(x, y, z)}")
    k = 1.0 / n
    return (x * k, y * k, z * k), n


def solve(
    acc: ArrayLike,
    mag: ArrayLike,
    mag_ref: ArrayLike,
    noise: NoiseModel,
    method: str = DEFAULT_METHOD,
    acc_ref: ArrayLike = ACC_REF_NED,
    q0: ArrayLike | None = None,
    *,
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = TOLERANCE_RAD,
    min_angle_deg: float = MIN_ANGLE_DEG,
) -> SolveResult:
    """Attitude from one accelerometer and one magnetometer sample.

    ``acc``, ``mag``: body FRD, any units (the accelerometer reads specific force, ``−g`` on z when
    level). ``mag_ref``, ``acc_ref``: the same quantities in NED (only their directions matter).
    ``q0``: warm start ``[w, x, y, z]`` or None. ``tolerance``: the attitude error (rad) left after the
    last Gauss–Newton correction, as estimated from the last two corrections. Raises :class:`InputError`
    for unusable numbers (zero, NaN or infinite vectors; a vector buried in its noise or a σ in other
    units, :func:`.kernel.weights_usable`) and :class:`DegenerateGeometryError` when either pair is
    within ``min_angle_deg`` of collinear, or so close to it for their weights that the normal matrix is
    singular in floating point.
    """
    check_method(method)
    sin_min = check_settings(max_iterations, tolerance, min_angle_deg)
    w_acc, n_acc = _unit("acc", acc)
    w_mag, n_mag = _unit("mag", mag)
    v_acc, _ = _unit("acc_ref", acc_ref)
    v_mag, _ = _unit("mag_ref", mag_ref)
    s_body = kernel.norm(kernel.cross(w_acc, w_mag))
    if not s_body >= sin_min:
        raise DegenerateGeometryError(geometry_message("acc and mag", s_body, min_angle_deg))
    s_ref = kernel.norm(kernel.cross(v_acc, v_mag))
    if not s_ref >= sin_min:
        raise DegenerateGeometryError(geometry_message("acc_ref and mag_ref", s_ref, min_angle_deg))

    a_mag, a_acc = kernel.paper_weight(w_mag, n_mag, noise.mag_var), kernel.paper_weight(w_acc, n_acc, noise.accel_var)
    if not kernel.weights_usable(a_mag, a_acc):
        raise InputError(weights_message(a_mag, a_acc))
    units, norms = (w_mag, v_mag, w_acc, v_acc), (n_acc, n_mag)
    obs = observations(method, noise, units, norms, (a_mag, a_acc))
    triad = quat_from_rotation_parts(kernel.triad(w_acc, w_mag, v_acc, v_mag, s_body, s_ref))
    rule = kernel.RULES[method]
    step, ml = rule.step, rule.matrix_weights
    q, iterations, done = triad, 0, step is None
    if step is not None:
        if q0 is not None:
            warm = _warm_start(q0)
            if kernel.wahba_loss(warm, obs, ml) <= kernel.wahba_loss(triad, obs, ml):
                q, iterations, done = _iterate(step, warm, obs, min(WARM_START_BUDGET, max_iterations), tolerance)
        if not done and iterations < max_iterations:
            q, extra, done = _iterate(step, triad, obs, max_iterations - iterations, tolerance)
            iterations += extra
    w, x, y, z = q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])
    return SolveResult(np.array((w, x, y, z)), iterations, bool(done), method, noise, units, norms, obs)


def _iterate(step, q: tuple, obs: tuple, budget: int, tolerance: float) -> tuple[tuple, int, bool]:
    """Steps (4)–(7): at most ``budget`` corrections; returns ``(q, corrections, converged)``.

    Once Eq. 34 is seen to converge slowly (:func:`.kernel.slow`) the rest are Newton corrections
    (the safeguard of :func:`.kernel.scalar_weight_step`; ``ml`` is Newton throughout). A step without a
    positive definite normal matrix raises :class:`DegenerateGeometryError`.
    """
    previous, newton = math.nan, False
    for k in range(1, budget + 1):
        q, angle = step(q, obs, newton)
        if angle != angle:  # NaN: no positive definite normal matrix (kernel module docstring)
            raise DegenerateGeometryError(SINGULAR_MESSAGE)
        if kernel.converged(angle, previous, tolerance):
            return q, k, True
        newton = newton or kernel.slow(angle, previous)
        previous = angle
    return q, budget, False


def _warm_start(q0: ArrayLike) -> tuple[float, float, float, float]:
    if type(q0) is np.ndarray:
        q0 = q0.tolist()
    try:
        w, x, y, z = (float(e) for e in q0)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise InputError(f"q0 must be a quaternion [w, x, y, z], got {q0!r}") from None
    n = (w * w + x * x + y * y + z * z) ** 0.5
    if not 0.0 < n < math.inf:
        raise InputError(f"q0 must be finite and non-zero, got {(w, x, y, z)}")
    return w / n, x / n, y / n, z / n
