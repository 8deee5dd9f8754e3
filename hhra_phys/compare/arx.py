"""The built-in ARX rows of the comparison: the paper's identification methods.

Registered on import, in the order of the paper's Table 3 (the paper's ARX structure, eq. 13,
by default ``na = nb = 3, nk = 1``): ``ls``, ``rls``, ``ffrls``, ``pso``, ``gwo``, ``hgwo``
(PSO, GWO, H-GWO on the box [-5, 5]) and ``ffrls_hgwo`` (the paper's hybrid); the estimators
are in :mod:`hhra_phys.arx`.

Initial conditions of the ARX free runs: the estimation part starts at rest at its first
measured output (past outputs ``y[0]``, past inputs 0); the validation part starts from the
measured samples just before the split (the usual "simulate from measured initial conditions";
with it the public record reproduces the baselines in ``docs/data.md``). After that
the output depends on the measured input only. Plug-in methods say in
``info["initial_condition"]`` how they start.
"""

from __future__ import annotations

import warnings
from typing import Any

from hhra_phys import arx
from hhra_phys.compare.registry import CompareSettings, MethodFn, MethodOutcome, register_method
from hhra_phys.data import Dataset
from hhra_phys.multi import RecordSet
from hhra_phys.optim.registry import LABELS

__all__ = ["ARX_METHODS", "arx_outcome"]


#: The built-in ARX methods, in the order of the paper's Table 3 (plus plain H-GWO).
ARX_METHODS: tuple[str, ...] = ("ls", "rls", "ffrls", "pso", "gwo", "hgwo", "ffrls_hgwo")

#: Display names of the ARX rows (registered with them); the metaheuristics' are the
#: optimisers' (:data:`hhra_phys.optim.registry.LABELS`).
_LABELS: dict[str, str] = {
    "ls": "LS",
    "rls": "RLS",
    "ffrls": "FFRLS",
    **{m: LABELS[m] for m in ("pso", "gwo", "hgwo")},
    "ffrls_hgwo": f"FFRLS+{LABELS['hgwo']}",
}


def _history_fields(fit: arx.ARXFit) -> dict[str, Any]:
    if fit.convergence is None:
        return {}
    return {
        "history": fit.convergence,
        "history_nfev": fit.convergence_nfev,
        "fitness": "ITAE of the free-run output on the estimation part",
    }


def arx_outcome(fit: arx.ARXFit, est: Dataset, val: Dataset) -> MethodOutcome:
    """A :class:`MethodOutcome` from an ARX fit: free runs on both parts (initial conditions:
    module docstring), with the model, its poles and the fit's details in ``info``.

    Parameters
    ----------
    fit : hhra_phys.arx.ARXFit
        The fitted model.
    est, val : Dataset
        Estimation and validation parts.
    """
    model = fit.model
    y_est = model.simulate(est.u, y_init=est.y[0], u_init=0.0)
    y_val = model.simulate(val.u, y_init=est.y, u_init=est.u)
    info: dict[str, Any] = {
        "model": model.to_dict(),
        "pole_radius": float(arx.pole_radius(model.a[None, :])[0]),
        "initial_condition": "est: at rest at y[0] (past u = 0); val: measured samples before "
        "the split",
        **fit.info,
    }
    if est.time_unit == "s" and model.na:
        s = model.continuous_poles(est.dt)
        info["continuous_poles"] = [[float(p.real), float(p.imag)] for p in s]
    return MethodOutcome(
        y_est,
        y_val,
        noi=fit.noi,
        nfev=fit.nfev,
        seconds=fit.seconds,
        info=info,
        **_history_fields(fit),
    )


def _orders(s: CompareSettings) -> dict[str, int]:
    return {"na": s.na, "nb": s.nb, "nk": s.nk}


def _signals(est: Any, time: bool = False) -> tuple[Any, ...]:
    """Input and output (and time with ``time``) of the estimation part, or lists of them
    for several records (:class:`~hhra_phys.multi.RecordSet`: regression rows stacked
    per record, ITAEs summed over the records)."""
    if isinstance(est, RecordSet):
        out = ([d.u for d in est], [d.y for d in est], [d.t for d in est])
    else:
        out = (est.u, est.y, est.t)
    return out if time else out[:2]


def _outcome(fit: arx.ARXFit, est: Any, val: Any) -> MethodOutcome:
    """:func:`arx_outcome`, or for several records one output per record."""
    if not isinstance(est, RecordSet):
        return arx_outcome(fit, est, val)
    outs = [arx_outcome(fit, e, v) for e, v in zip(est, val, strict=True)]
    first = outs[0]
    first.y_est, first.y_val = [o.y_est for o in outs], [o.y_val for o in outs]
    first.info["initial_condition"] += " (each record's own)"
    return first


def _method_ls(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", arx.ConditioningWarning)
        fit = arx.fit_ls(*_signals(est), **_orders(s))
    out = _outcome(fit, est, val)
    if caught:
        out.info["warnings"] = [str(w.message) for w in caught]
    return out


def _method_rls(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    return _outcome(arx.fit_rls(*_signals(est), **_orders(s)), est, val)


def _method_ffrls(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    return _outcome(arx.fit_ffrls(*_signals(est), **_orders(s)), est, val)


def _metaheuristic(method: str) -> MethodFn:
    def run(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
        fit = arx.fit_metaheuristic(
            *_signals(est, time=True),
            method=method,
            bounds=s.bounds,
            pop_size=s.pop_size,
            max_iter=s.max_iter,
            seed=s.seed,
            optimizer_options=s.options.get(method),
            progress=s.progress,
            **_orders(s),
        )
        return _outcome(fit, est, val)

    run.several_records = True  # type: ignore[attr-defined]
    run.__name__ = f"_method_{method}"
    run.__doc__ = f"ARX coefficients by {_LABELS[method]} minimising the free-run ITAE."
    return run


def _method_ffrls_hgwo(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
    fit = arx.fit_ffrls_hgwo(
        *_signals(est, time=True),
        zeta_s=s.zeta_s,
        pop_size=s.pop_size,
        max_iter=s.max_iter,
        seed=s.seed,
        optimizer_options=s.options.get("ffrls_hgwo"),
        progress=s.progress,
        **_orders(s),
    )
    return _outcome(fit, est, val)


# Every built-in row takes several records: the equation-error estimators on their
# regression rows stacked per record, the metaheuristics on the sum of their ITAEs.
for _fn in (_method_ls, _method_rls, _method_ffrls, _method_ffrls_hgwo):
    _fn.several_records = True  # type: ignore[attr-defined]


register_method("ls", _method_ls, label=_LABELS["ls"])
register_method("rls", _method_rls, label=_LABELS["rls"])
register_method("ffrls", _method_ffrls, label=_LABELS["ffrls"])
for _m in ("pso", "gwo", "hgwo"):
    register_method(_m, _metaheuristic(_m), label=_LABELS[_m])
register_method("ffrls_hgwo", _method_ffrls_hgwo, label=_LABELS["ffrls_hgwo"])
