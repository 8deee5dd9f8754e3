"""Physical-model rows of the method comparison (``hhra-phys compare``).

Registers, in the method registry (:mod:`hhra_phys.compare.registry`), when
:mod:`hhra_phys.compare` is imported, the physical HHRA fits so they are scored
on the same split and by the same free-run metrics as the ARX methods:

=====================  ============================================================
``phys_hgwo``          H-GWO over the groups (population and iterations of the comparison)
``phys_hgwo_ipopt``    the same, refined with IPOPT (exact CasADi derivatives)
``phys_hgwo_nlopt``    the same, refined with NLopt ``LD_LBFGS`` (CasADi gradient)
``phys_ipopt``         IPOPT alone from the nominal values (no global search)
=====================  ============================================================

The model is :func:`hhra_phys.fit.default_model`: the HHRA with the orifice
valve and an angle output, or a pressure output when the record's output is a
pressure, rescaled per sample for records without a sample time. The
validation output is a free-run simulation from the validation input with the
initial state estimated on the validation record (parameters fixed).
"""

from __future__ import annotations

import time

from hhra_phys.compare.registry import CompareSettings, MethodFn, MethodOutcome, register_method
from hhra_phys.data import Dataset
from hhra_phys.fit import fit
from hhra_phys.multi import RecordSet

__all__ = ["ROWS", "register"]

#: Method name -> (global optimiser, local refinement or None, display label).
ROWS: dict[str, tuple[str, str | None, str]] = {
    "phys_hgwo": ("hgwo", None, "physical H-GWO"),
    "phys_hgwo_ipopt": ("hgwo", "ipopt", "physical H-GWO+IPOPT"),
    "phys_hgwo_nlopt": ("hgwo", "nlopt", "physical H-GWO+NLopt"),
    "phys_ipopt": ("none", "ipopt", "physical IPOPT from nominal"),
}


def _method(optimizer: str, refine: str | None) -> MethodFn:
    def run(est: Dataset, val: Dataset, s: CompareSettings) -> MethodOutcome:
        t0 = time.perf_counter()
        extra = dict(s.extra.get("physical", {})) if s.extra else {}
        # No model given: fit.default_model (pressure output, per-sample time scale).
        model = extra.pop("model", None)
        several = isinstance(est, RecordSet)
        # Several records: one joint fit of their estimation parts (shared parameters,
        # an initial state per record), each part then predicted as one record's.
        res = fit(list(est) if several else est, model,
                  validation=None if several else val, split=1.0 if several else 0.5,
                  optimizer=optimizer, refine=refine or "none",
                  pop_size=s.pop_size, max_iter=s.max_iter, seed=s.seed,
                  progress=s.progress, **extra)
        seconds = time.perf_counter() - t0
        glob = next((st for st in res.stages if st["name"] == optimizer), None)
        nfev = sum(int(st["nfev"]) for st in res.stages)
        return MethodOutcome(
            y_est=[res.predict(d) for d in est] if several else res.predict(est),
            y_val=[res.predict(d) for d in val] if several else res.predict(val),
            noi=(glob or {}).get("info", {}).get("noi"),
            nfev=nfev, seconds=seconds,
            history=res.history or None,
            fitness=f"{res.settings['cost'].upper()} of the free-run output (estimation part)",
            info={"params": {n: res.values[n] for n in res.free if n in res.values},
                  "ci95": {n: list(v) for n, v in res.ci95.items()},
                  "stages": res.stages, "warnings": res.warnings},
        )

    run.several_records = True  # type: ignore[attr-defined]
    return run


# One function per row, made once, so registering again is a no-op, not a replacement.
_FUNCTIONS: dict[str, MethodFn] = {
    name: _method(optimizer, refine) for name, (optimizer, refine, _) in ROWS.items()
}


def register() -> None:
    """Register the physical rows; done on import of :mod:`hhra_phys.compare`.

    Idempotent: a row already registered with its own function is left as it is, so calling
    it again (after clearing :data:`~hhra_phys.compare.registry.METHODS`, say) only restores
    missing rows.

    Raises
    ------
    ParameterError
        If a row's name was registered meanwhile by another method (that one is kept).
    """
    for name, (_, _, label) in ROWS.items():
        register_method(name, _FUNCTIONS[name], label=label)


register()
