"""Identifiability at a fit's optimum: the Gauss-Newton covariance and its weak directions.

The module docstring of :mod:`hhra_phys.result` ("Uncertainty") as code:
:func:`uncertainty` gives the covariance of the fitting coordinates, their correlation and
the warnings about what the data cannot tell apart; :func:`weak_directions` names the
directions of parameter space the data do not determine (:func:`hhra_phys.result.redundant`
reads them off a fit to refuse a candidate that only reparametrises the model). Separate from
:mod:`hhra_phys.result` because it is linear algebra on a residual Jacobian, not the
result's record; every name here is also importable from :mod:`hhra_phys.result`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "uncertainty",
    "weak_directions",
]


#: Condition number of the scaled information matrix beyond which parameters are
#: reported as not identifiable from the data.
IDENTIFIABILITY_COND = 1e10
#: |correlation| beyond which a pair is reported as practically not separable.
CORRELATION_LIMIT = 0.999
#: Share of a weak direction (its unit eigenvector's component) from which a
#: parameter counts as involved in it.
WEAK_SHARE = 0.3


def weak_directions(J: np.ndarray, names: list[str]) -> list[dict[str, Any]]:
    """Directions of parameter space the data cannot determine.

    Parameters
    ----------
    J : ndarray, shape (N, n)
        Residual Jacobian at the optimum (fitting coordinates).
    names : list of str
        Free parameter names.

    Returns
    -------
    list of dict
        One per eigenvector of the scaled information matrix ``J^T J`` whose
        eigenvalue is below ``1/IDENTIFIABILITY_COND`` of the largest, weakest first:
        ``condition`` (largest eigenvalue over this one), ``params`` (name to the
        eigenvector's component, for components of at least ``WEAK_SHARE``) and
        ``reason`` (words). Parameters the output does not see at all are one
        direction each (``condition`` ``inf``). Empty when the matrix is well
        conditioned or not finite.
    """
    J = np.asarray(J, dtype=float)
    if J.ndim != 2 or J.shape[1] == 0 or not np.all(np.isfinite(J)):
        return []
    info = J.T @ J
    scale = np.sqrt(np.diag(info))
    out: list[dict[str, Any]] = []
    dead = ~(np.isfinite(scale) & (scale > 0))
    for i in np.flatnonzero(dead):
        out.append({"condition": float("inf"), "params": {names[i]: 1.0},
                    "reason": f"{names[i]} does not change the output at the optimum"})
    live = np.flatnonzero(~dead)
    if live.size < 2:
        return out
    normed = info[np.ix_(live, live)] / np.outer(scale[live], scale[live])
    eigval, eigvec = np.linalg.eigh(normed)
    top = max(float(eigval[-1]), np.finfo(float).tiny)
    for k in range(live.size):
        lam = float(eigval[k])
        cond = top / lam if lam > 0 else float("inf")  # rounding can make it <= 0
        if cond <= IDENTIFIABILITY_COND:
            break
        v = eigvec[:, k] / np.max(np.abs(eigvec[:, k]))
        v = v * np.sign(v[np.argmax(np.abs(v))])
        weights = {names[live[i]]: float(v[i]) for i in np.argsort(-np.abs(v))
                   if abs(eigvec[i, k]) >= WEAK_SHARE}
        if len(weights) < 1:
            continue
        combo = " with ".join(f"{n} ({w:+.3g})" for n, w in weights.items())
        out.append({"condition": float(cond), "params": weights,
                    "reason": f"moving {combo} together leaves the output unchanged "
                              f"(information-matrix condition {cond:.2g}): the data cannot "
                              "tell them apart"})
    return out




def uncertainty(
    J: np.ndarray, r: np.ndarray, names: list[str]
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Gauss-Newton covariance in fitting coordinates, correlation matrix, warnings.

    Parameters
    ----------
    J : ndarray, shape (N, n)
        Residual Jacobian at the optimum (fitting coordinates).
    r : ndarray, shape (N,)
        Residuals at the optimum.
    names : list of str
        Free parameter names (for the warnings).

    Returns
    -------
    cov : ndarray, shape (n, n)
        Covariance of the fitting coordinates (``inf`` on the diagonal of
        unidentifiable directions).
    corr : ndarray, shape (n, n)
        Correlation matrix.
    warnings : list of str
    """
    n_obs, n = J.shape
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        # A diverged simulation: no curvature to read, every interval is undetermined.
        cov = np.full((n, n), np.nan)
        np.fill_diagonal(cov, np.inf)
        return cov, np.eye(n), [
            "the residual or its Jacobian is not finite at the result (the simulation "
            "diverges there): confidence intervals are undetermined"]
    s2 = float(r @ r) / max(n_obs - n, 1)
    info = J.T @ J
    scale = np.sqrt(np.diag(info))
    dead = ~(np.isfinite(scale) & (scale > 0))
    warnings: list[str] = []
    if dead.any():
        warnings.append(
            f"parameters {', '.join(names[i] for i in np.flatnonzero(dead))} do not affect the "
            "output at the optimum: not identifiable from these data (intervals undetermined)"
        )
        scale = np.where(dead, 1.0, scale)
    normed = info / np.outer(scale, scale)
    eigval, eigvec = np.linalg.eigh(normed)
    with np.errstate(over="ignore"):  # an exactly singular matrix: condition inf
        cond = eigval[-1] / max(eigval[0], np.finfo(float).tiny)
    weak = cond > IDENTIFIABILITY_COND and not dead.all()
    if weak:
        w = np.abs(eigvec[:, 0])
        involved = [names[i] for i in np.argsort(-w) if w[i] > 0.3]
        warnings.append(
            f"information matrix near singular (condition {cond:.2e}): "
            f"{', '.join(involved)} are not identifiable separately from these data"
        )
    cov = s2 * _inverse(normed, singular=cond > IDENTIFIABILITY_COND or dead.any()) / np.outer(
        scale, scale)
    # A parameter the output does not see has no variance to report: infinite, so its
    # interval is marked undetermined rather than given the pseudo-inverse's zero.
    cov[dead, :] = np.nan
    cov[:, dead] = np.nan
    cov[dead, dead] = np.inf
    corr = _correlation(cov)
    # Parameters along a direction the data cannot determine: the pseudo-inverse
    # gives them a finite variance set by its cut-off, not by the data. Their
    # correlations are kept from it (they say which parameters trade off), their
    # variances become infinite (no interval).
    unresolved = _unresolved(eigval, eigvec) & ~dead if weak else np.zeros(n, dtype=bool)
    if unresolved.any():
        cov[unresolved, unresolved] = np.inf
        warnings.append(
            f"{', '.join(names[i] for i in np.flatnonzero(unresolved))}: no confidence "
            "interval, the data do not determine them (a direction of the information "
            "matrix with condition above "
            f"{IDENTIFIABILITY_COND:.0e}; see the warning above)")
    warnings += [f"{names[i]} and {names[j]} are correlated {corr[i, j]:+.4f}: "
                 "the data hardly separate them"
                 for i in range(n) for j in range(i + 1, n)
                 if abs(corr[i, j]) > CORRELATION_LIMIT]
    return cov, corr, warnings


def _inverse(normed: np.ndarray, singular: bool) -> np.ndarray:
    """Inverse of the scaled information matrix (pseudo-inverse when singular)."""
    if not singular:
        try:
            return np.linalg.inv(normed)
        except np.linalg.LinAlgError:  # exactly singular although well scaled
            pass
    return np.linalg.pinv(normed, rcond=1e-12)


def _unresolved(eigval: np.ndarray, eigvec: np.ndarray) -> np.ndarray:
    """Parameters with a share of at least ``WEAK_SHARE`` in a too-weak direction."""
    out = np.zeros(eigval.size, dtype=bool)
    for k in range(eigval.size):
        with np.errstate(over="ignore"):  # an exactly singular direction: condition inf
            cond = eigval[-1] / max(eigval[k], np.finfo(float).tiny)
        if cond <= IDENTIFIABILITY_COND:
            break
        out |= np.abs(eigvec[:, k]) >= WEAK_SHARE
    return out


def _correlation(cov: np.ndarray) -> np.ndarray:
    """Correlation matrix of ``cov`` (0 where a variance is not finite)."""
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    corr = np.where(np.isfinite(np.outer(sd, sd)), corr, 0.0)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    return corr
