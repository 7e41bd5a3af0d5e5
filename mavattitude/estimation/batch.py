"""The vectorised solver over N samples: the per-sample path's equations (:mod:`.kernel`) on arrays.

Every sample starts from TRIAD and iterates exactly as :func:`.solve.solve` does (a sample that has
converged takes no further correction, as the per-sample loop returns), so the two agree to rounding.
Work is done in chunks that fit the CPU cache.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ConvergenceError, DegenerateGeometryError, InputError
from . import kernel
from .conventions import ACC_REF_NED, quat_from_rotation_matrix
from .noise import NoiseModel
from .solve import (
    DEFAULT_METHOD,
    MAX_ITERATIONS,
    MIN_ANGLE_DEG,
    SINGULAR_MESSAGE,
    TOLERANCE_RAD,
    SolveResult,
    check_method,
    check_settings,
    geometry_message,
    observations,
    weights_message,
)

CHUNK = 4096


@dataclass(frozen=True)
class BatchResult:
    """Per-sample outcome of :func:`solve_batch` with ``full_output=True``."""

    q: NDArray[np.float64]  # (N, 4) [w, x, y, z], body → NED, w ≥ 0; NaN where not usable
    iterations: NDArray[np.int64]  # (N,)
    converged: NDArray[np.bool_]  # (N,)
    loss: NDArray[np.float64]  # (N,)
    usable: NDArray[np.bool_]  # (N,) passed the per-sample checks (all, unless skip_unusable)


def solve_batch(
    acc: ArrayLike,
    mag: ArrayLike,
    mag_ref: ArrayLike,
    noise: NoiseModel,
    method: str = DEFAULT_METHOD,
    acc_ref: ArrayLike = ACC_REF_NED,
    *,
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = TOLERANCE_RAD,
    min_angle_deg: float = MIN_ANGLE_DEG,
    full_output: bool = False,
    skip_unusable: bool = False,
) -> NDArray[np.float64] | BatchResult:
    """Attitudes ``(N, 4)`` of N samples ``acc, mag (N, 3)``; ``mag_ref``/``acc_ref`` are ``(3,)`` or ``(N, 3)``.

    Arguments as for :func:`.solve.solve`. A sample that fails the per-sample checks of ``solve`` raises
    (naming the first one), or with ``skip_unusable`` is left out: not solved, ``q`` NaN, marked in
    :attr:`BatchResult.usable`. A sample found singular while iterating raises
    (:class:`DegenerateGeometryError`, as in ``solve``). If a sample does not converge,
    ``full_output=False`` raises :class:`ConvergenceError`; ``full_output=True`` returns a
    :class:`BatchResult` with per-sample flags instead.
    """
    arrays, refusals = _checked(acc, mag, mag_ref, acc_ref, noise, method, max_iterations, tolerance, min_angle_deg)
    n = arrays[0].shape[0]
    with np.errstate(all="ignore"):  # the checks themselves catch what overflows or is NaN
        usable = _usable(refusals) if skip_unusable else _raise_first(refusals, n)
    if not usable.all():
        arrays = _rows(arrays, n, usable)
    out = _solve_checked(arrays, noise, method, max_iterations, tolerance)
    if not usable.all():
        out = _scatter(out, usable)
    if full_output:
        return out
    if not out.converged[usable].all():
        bad = np.flatnonzero(usable & ~out.converged)
        raise ConvergenceError(
            f"{bad.size} of {n} samples did not converge in {max_iterations} iterations (first: sample {bad[0]}); "
            "pass full_output=True for per-sample flags"
        )
    return out.q


def _solve_checked(arrays: tuple, noise: NoiseModel, method: str, max_iterations: int, tolerance: float) -> BatchResult:
    """Solve samples that passed the checks, chunk by chunk."""
    n = arrays[0].shape[0]
    out = BatchResult(
        np.empty((n, 4)), np.empty(n, dtype=np.int64), np.empty(n, dtype=bool), np.empty(n), np.ones(n, dtype=bool)
    )
    singular = np.zeros(n, dtype=bool)
    for start in range(0, n, CHUNK):
        sl = slice(start, min(start + CHUNK, n))
        q, iterations, converged, loss, singular[sl], _ = _solve_chunk(
            [_columns(a, sl) for a in arrays], noise, method, max_iterations, tolerance
        )
        out.q[sl], out.iterations[sl], out.converged[sl], out.loss[sl] = q, iterations, converged, loss
    _fail(DegenerateGeometryError, singular, SINGULAR_MESSAGE)
    return out


def _scatter(solved: BatchResult, usable: NDArray[np.bool_]) -> BatchResult:
    """The usable samples' results in their places among all samples; the others NaN, 0, not converged."""
    n = usable.size
    out = BatchResult(
        np.full((n, 4), np.nan), np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool), np.full(n, np.nan), usable
    )
    out.q[usable], out.iterations[usable], out.converged[usable], out.loss[usable] = (
        solved.q,
        solved.iterations,
        solved.converged,
        solved.loss,
    )
    return out


def _checked(
    acc: ArrayLike,
    mag: ArrayLike,
    mag_ref: ArrayLike,
    acc_ref: ArrayLike,
    noise: NoiseModel,
    method: str,
    max_iterations: int,
    tolerance: float,
    min_angle_deg: float,
) -> tuple[tuple[NDArray[np.float64], ...], Iterator[Refusal]]:
    """The arguments checked: ``(acc, mag, acc_ref, mag_ref)`` as ``(N, 3)`` arrays (a reference given once as
    ``(1, 3)``), and ``solve``'s per-sample checks on them (:func:`_refusals`, run as they are read: read them
    under ``np.errstate(all="ignore")``)."""
    check_method(method)
    sin_min = check_settings(max_iterations, tolerance, min_angle_deg)
    acc_a = _samples("acc", acc, None)
    n = acc_a.shape[0]
    arrays = (acc_a, _samples("mag", mag, n), _samples("acc_ref", acc_ref, n), _samples("mag_ref", mag_ref, n))
    return arrays, _refusals(*(np.broadcast_to(a, (n, 3)) for a in arrays), noise, sin_min, min_angle_deg)


def _rows(arrays: tuple[NDArray[np.float64], ...], n: int, index: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """The rows ``index`` of each of the N-row ``arrays``; a reference given once stays as it is."""
    return tuple(a[index] if a.shape[0] == n else a for a in arrays)


def _samples(name: str, v: ArrayLike, n: int | None) -> NDArray[np.float64]:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be numeric") from None
    if a.shape == (3,) and n is not None:
        return a[None, :]
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and a.shape[0] != n):
        want = "(N, 3)" if n is None else f"({n}, 3) or (3,)"
        raise InputError(f"{name} must have shape {want}, got {a.shape}")
    return a


def _columns(a: NDArray[np.float64], sl: slice) -> tuple:
    if a.shape[0] == 1:  # one reference for all samples: plain floats broadcast
        return tuple(float(e) for e in a[0])
    return tuple(np.ascontiguousarray(a[sl].T))


Refusal = tuple[type[InputError], NDArray[np.bool_], Callable[[int], str]]


def _refusals(acc, mag, acc_ref, mag_ref, noise: NoiseModel, sin_min: float, min_angle_deg: float) -> Iterator[Refusal]:
    """The per-sample path's input checks over all samples at once, in its order: for each, the error it
    raises, the samples it refuses and the message naming a refused sample."""
    units, norms = {}, {}
    for name, a in (("acc", acc), ("mag", mag), ("acc_ref", acc_ref), ("mag_ref", mag_ref)):
        n = np.linalg.norm(a, axis=1)
        yield (
            InputError,
            ~((n > 0.0) & (n < np.inf)),
            lambda i, name=name, a=a: f"{name} must be finite and non-zero, got {tuple(a[i].tolist())}",
        )
        units[name], norms[name] = a / n[:, None], n
    for what, (a, b) in (("acc and mag", ("acc", "mag")), ("acc_ref and mag_ref", ("acc_ref", "mag_ref"))):
        s = np.linalg.norm(np.cross(units[a], units[b]), axis=1)
        yield (
            DegenerateGeometryError,
            ~(s >= sin_min),
            lambda i, s=s, what=what: geometry_message(what, float(s[i]), min_angle_deg),
        )
    a_acc = kernel.paper_weight(tuple(units["acc"].T), norms["acc"], noise.accel_var)
    a_mag = kernel.paper_weight(tuple(units["mag"].T), norms["mag"], noise.mag_var)
    yield InputError, ~kernel.weights_usable(a_mag, a_acc), lambda i: weights_message(float(a_mag[i]), float(a_acc[i]))


def _raise_first(refusals: Iterator[Refusal], n: int) -> NDArray[np.bool_]:
    """Raise for the first check that refuses a sample, naming its first; all usable otherwise."""
    for error, bad, message in refusals:
        if bad.any():
            _fail(error, bad, message(int(np.flatnonzero(bad)[0])))
    return np.ones(n, dtype=bool)


def _usable(refusals: Iterator[Refusal]) -> NDArray[np.bool_]:
    """The samples no check refuses."""
    return ~np.logical_or.reduce([bad for _, bad, _ in refusals])


def _fail(error: type[InputError], bad: NDArray[np.bool_], message: str) -> None:
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise error(f"{message}: {int(bad.sum())} bad sample(s), first: sample {first}")


def _solve_chunk(chunk: list, noise: NoiseModel, method: str, max_iterations: int, tolerance: float) -> tuple:
    """Solve one chunk of checked samples; returns ``(q (n, 4), iterations, converged, loss, singular, inputs)``,
    ``singular`` where a step had no positive definite normal matrix (NaN from the kernel; the row keeps
    its last finite iterate and takes no further step), ``inputs`` the directions and norms solved
    (:attr:`.SolveResult._units`, ``_norms``), columns or floats."""
    (w_acc, n_acc), (w_mag, n_mag), (v_acc, _), (v_mag, _) = (kernel.unit(v) for v in chunk)
    s_body = kernel.norm(kernel.cross(w_acc, w_mag))
    s_ref = kernel.norm(kernel.cross(v_acc, v_mag))

    obs = observations(method, noise, (w_mag, v_mag, w_acc, v_acc), (n_acc, n_mag))
    r = np.stack(np.broadcast_arrays(*kernel.triad(w_acc, w_mag, v_acc, v_mag, s_body, s_ref)), -1)
    q = tuple(quat_from_rotation_matrix(r.reshape(-1, 3, 3)).T)
    rule = kernel.RULES[method]
    step, ml = rule.step, rule.matrix_weights
    size = q[0].shape[0]
    iterations = np.zeros(size, dtype=np.int64)
    done = np.full(size, step is None)
    previous = np.full(size, np.nan)
    newton = np.zeros(size, dtype=bool)
    singular = np.zeros(size, dtype=bool)
    for _ in range(max_iterations):
        if done.all():
            break
        q_next, angle = step(q, obs, newton if newton.any() else False)
        failed = ~done & np.isnan(angle)
        active = ~done & ~failed  # as solve(): a converged sample takes no further correction
        q = tuple(np.where(active, b, a) for a, b in zip(q, q_next, strict=True))
        iterations += active
        converged = kernel.converged(angle, previous, tolerance)
        newton = newton | (~converged & kernel.slow(angle, previous))
        done = done | (active & converged) | failed
        singular |= failed
        previous = angle
    qa = np.stack(q, -1)
    loss = kernel.wahba_loss(q, obs, ml)
    inputs = ((w_mag, v_mag, w_acc, v_acc), (n_acc, n_mag))
    return np.where(qa[:, :1] < 0.0, -qa, qa), iterations, done & ~singular, loss, singular, inputs


def solve_each(
    acc: ArrayLike,
    mag: ArrayLike,
    mag_ref: ArrayLike,
    noise: NoiseModel,
    method: str = DEFAULT_METHOD,
    acc_ref: ArrayLike = ACC_REF_NED,
    *,
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = TOLERANCE_RAD,
    min_angle_deg: float = MIN_ANGLE_DEG,
) -> list[SolveResult | InputError]:
    """:func:`.solve.solve` of each sample ``acc, mag (N, 3)``, solved together: for each its
    :class:`~.solve.SolveResult`, or the error ``solve`` raises for it (the first of ``solve``'s checks it fails,
    or a normal matrix singular while iterating), returned rather than raised. Answers equal ``solve``'s to
    rounding; for a stream of ticks solved one after another, an order of magnitude less time."""
    arrays, refusals = _checked(acc, mag, mag_ref, acc_ref, noise, method, max_iterations, tolerance, min_angle_deg)
    n = arrays[0].shape[0]
    out: list[SolveResult | InputError | None] = [None] * n
    with np.errstate(all="ignore"):  # the checks themselves catch what overflows or is NaN
        for error, bad, message in refusals:
            for i in np.flatnonzero(bad).tolist():
                out[i] = out[i] or error(message(i))
    rows = [i for i, r in enumerate(out) if r is None]
    checked = _rows(arrays, n, rows)
    for start in range(0, len(rows), CHUNK):
        sl = slice(start, min(start + CHUNK, len(rows)))
        q, iterations, converged, _, singular, (units, norms) = _solve_chunk(
            [_columns(a, sl) for a in checked], noise, method, max_iterations, tolerance
        )
        m = q.shape[0]
        units_rows = zip(*(_vectors(v, m) for v in units), strict=True)
        norms_rows = zip(*(_values(v, m) for v in norms), strict=True)
        flags = zip(iterations.tolist(), converged.tolist(), singular.tolist(), strict=True)
        for i, q_i, (k, ok, bad), units_i, norms_i in zip(rows[sl], q, flags, units_rows, norms_rows, strict=True):
            out[i] = (
                DegenerateGeometryError(SINGULAR_MESSAGE)
                if bad
                else SolveResult(q_i, k, ok, method, noise, units_i, norms_i)
            )
    return out  # type: ignore[return-value]


def _vectors(v: tuple, m: int) -> list[tuple[float, float, float]]:
    """A direction per row: ``v`` as columns, or one for all (floats)."""
    return list(zip(*(c.tolist() for c in v), strict=True)) if isinstance(v[0], np.ndarray) else [v] * m


def _values(v: NDArray[np.float64] | float, m: int) -> list[float]:
    return v.tolist() if isinstance(v, np.ndarray) else [v] * m
