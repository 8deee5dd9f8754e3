"""What a diagnosis returns (:class:`DiagnosisResult`, the loop's ``LoopResult``): the
base and final fits, every judged step, the test scores; its JSON, its summary and its
report.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from hhra_phys.diagnosis.discovery import DiscoveredStep
from hhra_phys.diagnosis.residual import Diagnosis
from hhra_phys.diagnosis.selection import METRIC_KEYS, Step
from hhra_phys.errors import ParameterError
from hhra_phys.outputs import jsonable
from hhra_phys.result import FitResult, format_metric

__all__ = ["DiagnosisResult", "LoopResult", "summary_lines"]


@dataclass
class DiagnosisResult:
    """Outcome of a diagnosis (:func:`hhra_phys.diagnose`, the loop).

    :meth:`to_json` is the diagnose JSON (and :meth:`from_json` reads it back);
    :meth:`report` writes the Markdown report and its figures.
    """

    base: FitResult
    final: FitResult
    steps: list[Step]
    chosen: list[str]
    diagnoses: list[Diagnosis]
    final_diagnosis: Diagnosis | None
    settings: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    #: Candidates that could not be tried on this model, with the reason.
    skipped: dict[str, str] = field(default_factory=dict)
    #: Scores on the test part, which chose nothing: ``{"base": {...}, "final": {...}}``
    #: (empty dictionaries with ``test=0``).
    test_scores: dict[str, dict[str, float]] = field(default_factory=dict)
    #: The record(s) the loop ran on (:func:`~hhra_phys.diagnosis.engine.diagnose`'s
    #: ``data``), for :meth:`report`'s figures; ``None`` for a result read with
    #: :meth:`from_json`. Not saved.
    data: Any = field(default=None, repr=False, compare=False)
    #: The diagnoses' JSON summaries of a result read with :meth:`from_json` (the live
    #: :class:`~hhra_phys.diagnosis.residual.Diagnosis` objects, with their arrays, are not saved).
    saved_diagnoses: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def test(self) -> dict[str, float]:
        """The final model's scores on the untouched test part (``rmse``, ``vaf``, ...)."""
        return dict(self.test_scores.get("final", {}))

    def summary(self) -> str:
        """What ``hhra-phys diagnose`` prints after the loop: the chosen effects, the RMSE
        and VAF of each part before -> after (``est``, ``val`` the selection part, ``test``),
        each record's with several, and the final fit's derived quantities with their 95 %
        intervals. Units are the records'; warnings are :attr:`warnings` and the final
        fit's (not repeated here)."""
        return "\n".join(summary_lines(self, self.to_json()))

    def report(self, path: str | Any, data: Any = None, overwrite: bool = False) -> Any:
        """Write the Markdown report and its residual figures (``hhra-phys diagnose
        --report``'s; :func:`hhra_phys.report.loop_report`).

        Parameters
        ----------
        path : str or path-like
            The report (``.md``); figures ``<stem>_before.png``, ``<stem>_after.png``
            and, when discovery built terms, ``<stem>_discovery.png`` go beside it.
        data : Dataset or sequence of Dataset, optional
            The loop's record(s) (default: the ones
            :func:`~hhra_phys.diagnosis.engine.diagnose` kept).
        overwrite : bool
            Replace existing files.

        Returns
        -------
        pathlib.Path
        """
        from hhra_phys.report import loop_report

        return loop_report(self, path, data=data, overwrite=overwrite)

    def to_json(self) -> dict[str, Any]:
        """The diagnose JSON.

        ``base`` and ``final`` hold ``est`` (estimation), ``val`` (the selection part,
        which chose the effects; the key keeps its old name) and ``test`` (the
        untouched test part) scores; ``test`` at top level is the final model's test
        score, ``steps``, ``chosen``, ``skipped`` as before; ``stopped_by_budget``
        whether :attr:`LoopOptions.budget` ended the loop early. ``fits`` holds the base
        and final fits whole, once (:meth:`FitResult.to_json
        <hhra_phys.result.FitResult.to_json>`: ``params[NAME]`` with ``value``, ``ci95``
        and ``free``, the derived quantities, warnings and intervals),
        ``test_scores`` and ``loop_warnings`` what :meth:`from_json` needs besides.
        """
        def part(res: FitResult, key: str) -> dict[str, Any]:
            out = {k: {m: res.metrics[k].get(m) for m in METRIC_KEYS}
                   for k in ("est", "val") if res.metrics.get(k)}
            if self.test_scores.get(key):
                out["test"] = {m: self.test_scores[key].get(m) for m in METRIC_KEYS}
            if res.records:  # several records: each one's scores ("sel": its selection part)
                out["records"] = [
                    {"name": r["name"], **{k: {m: r.get(src, {}).get(m) for m in METRIC_KEYS}
                                           for k, src in (("est", "est"), ("sel", "val"),
                                                          ("test", "test"))}}
                    for r in res.records]
            return {**out, **{k: v for k, v in res.settings.items() if k == "widened"}}

        # Each fit once: its parameters with their intervals, its warnings and how the
        # intervals were had are in ``fits`` (``fits.final.params[NAME]``: ``value``,
        # ``ci95``, ``free``); ``base`` and ``final`` hold the loop's scores of them.
        final = part(self.final, "final")
        saved = self.saved_diagnoses
        return jsonable({
            "base": part(self.base, "base"),
            "test": ({m: self.test_scores["final"].get(m) for m in METRIC_KEYS}
                     if self.test_scores.get("final") else None),
            "steps": [s.to_json() for s in self.steps],
            "chosen": list(self.chosen),
            "final": final,
            "diagnosis_before": (self.diagnoses[0].to_json() if self.diagnoses
                                 else saved.get("diagnosis_before")),
            "diagnosis_after": (self.final_diagnosis.to_json()
                                if self.final_diagnosis is not None
                                else saved.get("diagnosis_after")),
            "warnings": self.warnings + [w for w in self.final.warnings
                                         if w not in self.warnings],
            "skipped": dict(self.skipped),
            "settings": self.settings,
            "stopped_by_budget": bool(self.settings.get("stopped_by_budget", False)),
            "fits": {"base": self.base.to_json(), "final": self.final.to_json()},
            "test_scores": self.test_scores,
            "loop_warnings": list(self.warnings),
        })

    @classmethod
    def from_json(cls, d: Mapping[str, Any], source: str = "diagnose result"
                  ) -> DiagnosisResult:
        """The result of :meth:`to_json`'s dictionary.

        The fits, steps, choices, settings and scores come back; the diagnoses only as
        their JSON summaries (:attr:`saved_diagnoses`), so :meth:`report` of a read
        result has no evidence section and no figures.

        Raises
        ------
        ParameterError
            A dictionary without the whole fits (written before ``fits`` was kept).
        """
        if not isinstance(d.get("fits"), Mapping):
            raise ParameterError(f"{source}: no 'fits' (a diagnose JSON written before the "
                                 "fits were kept cannot be read back)")
        return cls(
            base=FitResult.from_json(d["fits"]["base"], source=f"{source} base fit"),
            final=FitResult.from_json(d["fits"]["final"], source=f"{source} final fit"),
            steps=[_step_from_json(s) for s in d.get("steps", [])],
            chosen=list(d.get("chosen", [])),
            diagnoses=[], final_diagnosis=None,
            settings=dict(d.get("settings", {})),
            warnings=list(d.get("loop_warnings", [])),
            skipped=dict(d.get("skipped", {})),
            test_scores={k: dict(v) for k, v in (d.get("test_scores") or {}).items()},
            saved_diagnoses={k: d[k] for k in ("diagnosis_before", "diagnosis_after")
                             if d.get(k) is not None},
        )



#: The result's first name (``hhra_phys.loop.LoopResult``), kept for the code that uses it.
LoopResult = DiagnosisResult

def _twins_text(step: Step) -> str:
    """`` (the discovered form of coulomb_friction)`` for a discovered step that holds a
    library effect's shape (:func:`~hhra_phys.effects.library_twins`), else empty."""
    same = getattr(step, "same_as", ())
    return f" (the discovered form of {' and '.join(same)})" if same else ""


def _step_from_json(d: Mapping[str, Any]) -> Step:
    """A :class:`Step` (or discovered one) of :meth:`Step.to_json`'s dictionary."""
    own = {f.name for f in fields(Step)}
    kw = {k: v for k, v in d.items() if k in own}
    kw["ci95"] = {n: [math.nan if c is None else c for c in v]
                  for n, v in (d.get("ci95") or {}).items()}
    for k in ("criterion", "criterion_before", "val_rmse_before"):  # null: NaN when written
        kw[k] = math.nan if kw.get(k) is None else kw[k]
    if not d.get("discovered"):
        return Step(**kw)
    extra = ("expression", "uses", "method", "screening", "extrapolated", "same_as")
    return DiscoveredStep(**kw, **{k: d[k] for k in extra if k in d})


def summary_lines(res: DiagnosisResult, out: Mapping[str, Any]) -> list[str]:
    """:meth:`DiagnosisResult.summary`'s lines from the result and its JSON ``out``
    (:meth:`DiagnosisResult.to_json`, passed in where it is already built)."""
    fm = format_metric
    lines = [f"chosen: {', '.join(res.chosen) or 'none'}"]
    for part in ("est", "val", "test"):
        b, f = out["base"].get(part, {}), out["final"].get(part, {})
        if f:
            lines.append(f"{part}: RMSE {fm(b.get('rmse'))} -> {fm(f.get('rmse'))}, "
                         f"VAF {fm(b.get('vaf'))} -> {fm(f.get('vaf'))} %")
    for rb, rf in zip(out["base"].get("records", []), out["final"].get("records", []),
                      strict=True):
        lines.append(f"record {rf['name']}: " + ", ".join(
            f"{part} RMSE {fm(rb[part]['rmse'])} -> {fm(rf[part]['rmse'])}"
            for part in ("est", "sel", "test") if rf[part].get("rmse") is not None))
    for name, est in res.final.derived.items():
        if est.free:
            ci = est.ci95 or (math.nan, math.nan)
            lines.append(f"derived {name} = {fm(est.value)} {est.unit}, 95 % CI "
                         f"[{fm(ci[0])}, {fm(ci[1])}]")
    return lines
