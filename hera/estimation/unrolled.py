"""Straight-line steps on Python floats for small states (the numpy backend's fast path).

At the sizes a fusion model has (n <= 6 states, one block of m <= 3 rows), numpy's cost is
its call overhead, about 1-2 us a call and some 25 calls a predict and update, not the
arithmetic (a few hundred multiply-adds). So for each size this module writes the step out
as Python source, every matrix element a local variable, and compiles it once per process
(:func:`functools.cache`): CPython then does each multiply-add in a few tens of ns.

The equations are those of the numpy path, term for term:

* :func:`predict_step`: x = F x and P = F P F^T + Q (seed 003 eq. 5; the EKF's
  covariance, eq. 7, without x), the upper triangle computed and mirrored, so P is
  exactly symmetric;
* :func:`linear_update`: the joint update of ``correction`` for one block: G = H P,
  S = G H^T + R, S = L L^T (Cholesky, the positive-definiteness test), NIS = |L^-1 y|^2,
  the chi-square gate, K^T = L^-T (L^-1 G), x += K y, and the Joseph form as
  T = P - K G, P = T + (K R - T H^T) K^T (or the short form T), symmetrised. Several
  blocks of 1-3 rows in all run as one stacked block (``with_s``: S is returned so that
  the caller computes each block's own NIS and gate from its diagonal sub-block).

The generated functions take and give flat row-major lists and never raise: a step that
meets a non-finite value or an S that is not positive definite returns None. The filters
call them through :func:`predict`, :func:`predict_covariance` and :func:`update_block`,
which convert numpy arrays at the edges and also return None, so the caller runs its
numpy path, which names the culprit. Agreement with the numpy path is tested to 1e-12 at
every supported size (``tests/estimation/test_unrolled.py``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = [
    "MAX_M",
    "MAX_N",
    "Memo",
    "linear_update",
    "predict",
    "predict_covariance",
    "predict_step",
    "update_block",
]

MAX_N = 6
"""The largest state this path takes. Above it the unrolled arithmetic (n^3 terms a predict)
costs more than numpy's calls (measured with ``hera bench kalman --backend numpy``)."""

MAX_M = 3
"""The largest block (rows) of an unrolled update; the numpy path factorises larger ones."""

_GLOBALS = {"sqrt": math.sqrt, "isfinite": math.isfinite, "INF": math.inf, "__builtins__": {}}


def _compile(name: str, lines: list[str]) -> Callable[..., Any]:
    """The function ``name`` defined by ``lines`` (its source, indented by the caller)."""
    namespace: dict[str, Any] = dict(_GLOBALS)
    exec(compile("\n".join(lines) + "\n", f"<hera.estimation.unrolled {name}>", "exec"), namespace)
    return namespace[name]


def _flat(prefix: str, rows: int, cols: int) -> list[str]:
    return [f"{prefix}{i}_{j}" for i in range(rows) for j in range(cols)]


def _unpack(names: list[str], source: str) -> str:
    """An unpacking line (a trailing comma keeps a single name a tuple target)."""
    return f"    {', '.join(names)}, = {source}"


def _sum(terms: list[str]) -> str:
    return " + ".join(terms) if terms else "0.0"


Pattern = tuple[bool, ...] | None
"""Which entries of a matrix (flat, row-major) may be non-zero; None: all of them."""


def _nonzero(pattern: Pattern, rows: int, cols: int) -> Callable[[int, int], bool]:
    """Whether entry (i, j) of a rows x cols matrix with this pattern enters a product. A
    term of an entry that is exactly 0 is left out of the code: 0 x p is 0 for the finite
    P of a filter, and an entry that is not 0 in a later call selects another function."""
    if pattern is None:
        return lambda i, j: True
    if len(pattern) != rows * cols:
        raise ValueError(f"a pattern of {len(pattern)} entries for a {rows} x {cols} matrix")
    return lambda i, j: pattern[i * cols + j]


@functools.cache
def predict_step(n: int, f_nz: Pattern = None, state: bool = True) -> Callable[..., Any]:
    """``f(x, P, F, Q) -> (F x, F P F^T + Q)``, or with ``state=False`` ``f(P, F, Q) ->
    F P F^T + Q`` (the EKF, whose x comes from f(x)). x a list of n floats, the matrices
    flat (n*n) row-major; P' is exactly symmetric (its upper triangle computed, then
    mirrored). ``f_nz``: which entries of F may be non-zero, None: all."""
    _check_n(n)
    nz = _nonzero(f_nz, n, n)
    lines = [
        "def predict_step(x, P, F, Q):" if state else "def predict_step(P, F, Q):",
        _unpack(_flat("p", n, n), "P"),
        _unpack(_flat("f", n, n), "F"),
        _unpack(_flat("q", n, n), "Q"),
    ]
    if state:
        lines.append(_unpack([f"x{i}" for i in range(n)], "x"))
    for i in range(n):  # A = F P
        for k in range(n):
            terms = [f"f{i}_{j} * p{j}_{k}" for j in range(n) if nz(i, j)]
            lines.append(f"    a{i}_{k} = " + _sum(terms))
    for i in range(n):  # upper triangle of A F^T, plus Q
        for j in range(i, n):
            terms = [f"a{i}_{k} * f{j}_{k}" for k in range(n) if nz(j, k)]
            lines.append(f"    r{i}_{j} = " + _sum(terms) + f" + q{i}_{j}")
    cov = "[" + ", ".join(f"r{min(i, j)}_{max(i, j)}" for i in range(n) for j in range(n)) + "]"
    if state:
        xs = [_sum([f"f{i}_{k} * x{k}" for k in range(n) if nz(i, k)]) for i in range(n)]
        lines.append(f"    return [{', '.join(xs)}], {cov}")
    else:
        lines.append(f"    return {cov}")
    return _compile("predict_step", lines)


@functools.cache
def linear_update(
    n: int,
    m: int,
    full_noise: bool,
    joseph: bool,
    h_nz: Pattern = None,
    innovation: bool = False,
    with_s: bool = False,
) -> Callable[..., tuple[Any, ...] | None]:
    """``f(x, P, H, y, noise, thr) -> (nis, x', P')`` for one block of m rows on n states.

    x a list of n floats, P flat (n*n), H flat (m*n), y the innovation (m), ``noise`` the
    m variances (R diagonal) or, with ``full_noise``, R flat (m*m); ``thr`` the gate's
    chi-square threshold (``inf``: no gate); ``h_nz``: which entries of H may be non-zero,
    None: all; ``innovation``: the fourth argument is z, and y = z - H x is computed here
    (a linear block). Returns (nis, None, None) when the block is gated out (nis > thr),
    None when y or S = H P H^T + R is not finite or S is not positive definite (the
    caller's numpy path then raises the precise error), else the NIS, the updated x and
    the updated P (Joseph form when ``joseph``), symmetrised. P' is not checked here: the
    caller tests its diagonal and finiteness as the numpy path does. ``with_s``: a fourth
    value, the lower triangle of S as ragged rows ``[[s00], [s10, s11], ...]`` (the rows
    of several stacked blocks: their own NIS come from its diagonal sub-blocks).
    """
    _check_n(n)
    if not 1 <= m <= MAX_M:
        raise ValueError(f"an unrolled update takes 1 to {MAX_M} rows, got {m}")
    nz = _nonzero(h_nz, m, n)
    L = [
        "def linear_update(x, P, H, y, noise, thr):",
        _unpack([f"x{i}" for i in range(n)], "x"),
        _unpack(_flat("p", n, n), "P"),
        _unpack(_flat("h", m, n), "H"),
        _unpack([f"z{i}" if innovation else f"y{i}" for i in range(m)], "y"),
        _unpack(_flat("r", m, m) if full_noise else [f"v{i}" for i in range(m)], "noise"),
    ]
    if innovation:  # y = z - H x
        for i in range(m):
            hx = _sum([f"h{i}_{j} * x{j}" for j in range(n) if nz(i, j)])
            L.append(f"    y{i} = z{i} - ({hx})")

    def noise(i: int, j: int) -> str | None:
        if full_noise:
            return f"r{i}_{j}"
        return f"v{i}" if i == j else None

    for i in range(m):  # G = H P
        for k in range(n):
            L.append(
                f"    g{i}_{k} = " + _sum([f"h{i}_{j} * p{j}_{k}" for j in range(n) if nz(i, j)])
            )
    for i in range(m):  # lower triangle of S = G H^T + R
        for j in range(i + 1):
            terms = [f"g{i}_{k} * h{j}_{k}" for k in range(n) if nz(j, k)]
            r = noise(i, j)
            L.append(f"    s{i}_{j} = " + _sum(terms) + (f" + {r}" if r else ""))
    for j in range(m):  # Cholesky S = L L^T (small.chol_small, unrolled)
        d = " - ".join([f"s{j}_{j}"] + [f"l{j}_{p} * l{j}_{p}" for p in range(j)])
        L += [f"    d = {d}", "    if not 0.0 < d < INF:", "        return None"]
        L.append(f"    l{j}_{j} = sqrt(d)")
        for i in range(j + 1, m):
            t = " - ".join([f"s{i}_{j}"] + [f"l{i}_{p} * l{j}_{p}" for p in range(j)])
            L += [f"    t = {t}", "    if not isfinite(t):", "        return None"]
            L.append(f"    l{i}_{j} = t / l{j}_{j}")
    for c in range(m):  # L^-1 by forward substitution (small.lower_inverse)
        L.append(f"    i{c}_{c} = 1.0 / l{c}_{c}")
        for i in range(c + 1, m):
            terms = " + ".join(f"l{i}_{p} * i{p}_{c}" for p in range(c, i))
            L.append(f"    i{i}_{c} = -({terms}) / l{i}_{i}")
    for i in range(m):  # w = L^-1 y, NIS = |w|^2
        L.append(f"    w{i} = " + _sum([f"i{i}_{p} * y{p}" for p in range(i + 1)]))
    L += [
        "    nis = " + _sum([f"w{i} * w{i}" for i in range(m)]),
        "    if not nis < INF:",
        "        return None",
        "    if not nis <= thr:",
        "        return nis, None, None",
    ]
    for i in range(m):  # V = L^-1 G
        for k in range(n):
            L.append(f"    u{i}_{k} = " + _sum([f"i{i}_{p} * g{p}_{k}" for p in range(i + 1)]))
    for j in range(m):  # K^T = L^-T V; k{j}_{i} holds K[i, j]
        for i in range(n):
            L.append(f"    k{j}_{i} = " + _sum([f"i{p}_{j} * u{p}_{i}" for p in range(j, m)]))
    xs = [f"x{i} + " + _sum([f"k{j}_{i} * y{j}" for j in range(m)]) for i in range(n)]
    for i in range(n):  # T = P - K G
        for k in range(n):
            terms = " - ".join(f"k{j}_{i} * g{j}_{k}" for j in range(m))
            L.append(f"    t{i}_{k} = p{i}_{k} - {terms}")
    if joseph:
        for i in range(n):  # W = K R - T H^T
            for j in range(m):
                kr = [f"k{q}_{i} * {noise(q, j)}" for q in range(m) if noise(q, j)]
                th = [f"t{i}_{k} * h{j}_{k}" for k in range(n) if nz(j, k)]
                L.append(f"    e{i}_{j} = {_sum(kr)} - ({_sum(th)})")
        for i in range(n):  # T += W K^T
            for k in range(n):
                L.append(f"    t{i}_{k} += " + _sum([f"e{i}_{j} * k{j}_{k}" for j in range(m)]))
    for i in range(n):
        for k in range(i, n):
            L.append(f"    o{i}_{k} = 0.5 * (t{i}_{k} + t{k}_{i})")
    out = [f"o{min(i, k)}_{max(i, k)}" for i in range(n) for k in range(n)]
    ret = f"    return nis, [{', '.join(xs)}], [{', '.join(out)}]"
    if with_s:
        rows = ", ".join("[" + ", ".join(f"s{i}_{j}" for j in range(i + 1)) + "]" for i in range(m))
        ret += f", [{rows}]"
    L.append(ret)
    return _compile("linear_update", L)


def _check_n(n: int) -> None:
    if not 1 <= n <= MAX_N:
        raise ValueError(f"an unrolled step takes 1 to {MAX_N} states, got {n}")


_array = np.array
_isfinite = math.isfinite


def _finite(values: list[float]) -> bool:
    """Every value finite: the sum first (not finite iff a value is, or on overflow, which
    the full test then clears), as ``numerics.finite``."""
    return _isfinite(sum(values)) or all(map(_isfinite, values))


PATTERNS_PER_SIZE = 8
"""How many zero patterns of F (or H) one size compiles before its steps go dense: a
Jacobian whose zeros come and go would otherwise compile a function every call."""

_seen: dict[tuple[Any, ...], set[tuple[bool, ...]]] = {}


def _pattern(size: tuple[Any, ...], values: list[float]) -> Pattern:
    """The zero pattern of ``values`` (None, dense, once ``size`` has had its share)."""
    p = tuple(map(bool, values))
    seen = _seen.setdefault(size, set())
    if p not in seen:
        if len(seen) >= PATTERNS_PER_SIZE:
            return None
        seen.add(p)
    return p


class Memo(list):  # type: ignore[type-arg]
    """What :func:`predict` keeps for a filter between calls: [F as a list, its step]. It
    pickles and copies as empty (a generated function does not pickle; the step is found
    again at the next predict), so a filter that holds one still pickles."""

    __slots__ = ()

    def __reduce__(self) -> tuple[type, tuple[()]]:
        return Memo, ()


def predict(
    x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray, memo: list[Any] | None = None
) -> tuple[np.ndarray, np.ndarray] | None:
    """(F x, F P F^T + Q) for n <= MAX_N (float64 arrays), P exactly symmetric; None when a
    value is not finite. ``memo``: a :class:`Memo` the caller keeps (a filter's own);
    while F holds the same values its step is reused without reading F's zero pattern
    again (a list comparison, so an F changed in place is seen)."""
    n = x.shape[0]
    Fl = F.ravel().tolist()
    fn = _step_for(Fl, n, True, memo)
    xl, Pl = fn(x.tolist(), P.ravel().tolist(), Fl, Q.ravel().tolist())
    if not (_finite(Pl) and _finite(xl)):
        return None
    return _array(xl), _array(Pl).reshape(n, n)


def predict_covariance(
    P: np.ndarray, F: np.ndarray, Q: np.ndarray, memo: list[Any] | None = None
) -> np.ndarray | None:
    """F P F^T + Q as :func:`predict` (the EKF's covariance); None when not finite."""
    n = P.shape[0]
    Fl = F.ravel().tolist()
    out = _step_for(Fl, n, False, memo)(P.ravel().tolist(), Fl, Q.ravel().tolist())
    if not _finite(out):
        return None
    return _array(out).reshape(n, n)


def _step_for(Fl: list[float], n: int, state: bool, memo: list[Any] | None) -> Callable[..., Any]:
    """The predict step for F (flat ``Fl``): the memo's while F's values are the same."""
    if memo and memo[0] == Fl:
        return memo[1]
    fn = predict_step(n, _pattern(("F", n), Fl), state)
    if memo is not None:
        memo[:] = (Fl, fn)
    return fn


def update_block(
    x: np.ndarray,
    P: np.ndarray,
    H: np.ndarray,
    y: np.ndarray,
    var: np.ndarray | None,
    R: np.ndarray | None,
    thr: float,
    joseph: bool,
    innovation: bool = False,
    with_s: bool = False,
) -> tuple[Any, ...] | None:
    """The update of :func:`linear_update` on arrays (n <= MAX_N, m <= MAX_M rows; ``var``
    the variances of a diagonal R, else ``R``; with ``innovation``, ``y`` is z and the
    innovation z - H x is computed here): (nis, x', P'), or (nis, None, None) when gated
    out (nis > thr); ``with_s`` adds S's lower triangle (see :func:`linear_update`). None
    when the numpy path must decide: y or S not finite, S not positive definite, or P'
    with a non-finite value or a diagonal entry <= 0."""
    full = var is None
    noise = (R if full else var).ravel().tolist()  # type: ignore[union-attr]
    Hl = H.ravel().tolist()
    return update_rows(x, P, Hl, y.tolist(), noise, full, thr, joseph, innovation, with_s)


def update_rows(
    x: np.ndarray,
    P: np.ndarray,
    Hl: list[float],
    yl: list[float],
    noise: list[float],
    full: bool,
    thr: float,
    joseph: bool,
    innovation: bool = False,
    with_s: bool = False,
) -> tuple[Any, ...] | None:
    """:func:`update_block` with the rows already on Python floats: H row-major ``Hl``,
    ``yl`` (y, or z with ``innovation``), ``noise`` the variances or, when ``full``, R
    row-major. Returns as :func:`update_block`."""
    n, m = P.shape[0], len(yl)
    fn = linear_update(n, m, full, joseph, _pattern(("H", n, m), Hl), innovation, with_s)
    out = fn(x.tolist(), P.ravel().tolist(), Hl, yl, noise, thr)
    if out is None or out[1] is None:
        return out  # type: ignore[return-value]
    Pl = out[2]
    if not (min(Pl[:: n + 1]) > 0.0 and _finite(Pl) and _finite(out[1])):
        return None
    if with_s:
        return out[0], _array(out[1]), _array(Pl).reshape(n, n), out[3]
    return out[0], _array(out[1]), _array(Pl).reshape(n, n)
