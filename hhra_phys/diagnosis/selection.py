"""The one rule of model selection: which candidate joins the model, which leaves, when to stop.

Every path that adds or removes a part of a model (library effects, user effects,
discovered terms and modes, the backward step; one record or several) judges its
candidates here, so that they are compared by the same numbers:

- :func:`acceptance`: a candidate joins only if, on the selection part, its RMSE falls by
  the margin, the variance it removes exceeds what noise and structural mismatch allow
  (:func:`noise_allowance`), and the information criterion on estimation
  (:func:`information_criterion`) falls;
- :func:`choose`: of the acceptable candidates of a round, those the selection part cannot
  tell from the best (within the noise allowance of it) are told apart by the information
  criterion on estimation, the lowest wins;
- :func:`round_settled`: once a candidate leaves both parts at the noise level, no later
  candidate of the round can beat it by more than the allowance, so the round's remaining
  refits of its kind are skipped (the other kind goes on until one of its own settles, so
  that the tie rule, not the ranking, decides between a library effect and a discovered
  term);
- :func:`needs_rotation` / :func:`rotated_verdict`: the one verdict where the evidence
  disagrees. Both votes (:func:`votes`: the selection part's, the criterion's) must say yes,
  except where the part that says no holds the candidate's regime thinly or holds only a
  few samples of it (:func:`thin_parts`): such a part cannot refuse alone, so the parts
  rotate (the candidate and the current model refitted on selection, scored on estimation,
  or over more contiguous folds) and the held-out error over the folds decides, the same for
  every kind of candidate;
- :func:`backward_decision`: an accepted part stays only if it would be accepted now;
- :func:`stops_at_noise` / :func:`at_noise_level`: the loop stops when both the estimation
  and the selection residual are at the noise level.

:class:`Step` records one judged candidate; :func:`split_record` makes the parts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

from hhra_phys.data import Dataset
from hhra_phys.errors import ParameterError
from hhra_phys.result import FitResult

__all__ = [
    "NOISE_TOL",
    "NOISE_Z",
    "DECISIVE_CRITERION",
    "noise_tolerance",
    "METRIC_KEYS",
    "Step",
    "information_criterion",
    "estimation_samples",
    "noise_allowance",
    "acceptance",
    "judge",
    "choose",
    "tie_break",
    "round_settled",
    "backward_decision",
    "COLOURED_P",
    "at_noise_level",
    "stops_at_noise",
    "split_record",
    "REGIME_THIN",
    "REGIME_MIN_SAMPLES",
    "votes",
    "regime_samples",
    "thin_parts",
    "thin_part",
    "needs_rotation",
    "PAIR_CANDIDATES",
    "contradicts",
    "pooled_rmse",
    "rotated_verdict",
]

#: Structural-mismatch allowance of the stopping and acceptance rule (fraction of
#: the noise level); measured on independently simulated records, docs/diagnosis.md.
NOISE_TOL = 0.15


#: Standard errors of a residual's mean square that :func:`noise_tolerance` grants.
NOISE_Z = 2.0


#: Difference of the information criterion that overrides :func:`choose`'s preference for
#: a sensor effect among tied candidates: above 10 BIC units the evidence is "very strong"
#: on the usual scale (a Bayes factor above about 150), below it the preference decides.
DECISIVE_CRITERION = 10.0


METRIC_KEYS = ("rmse", "vaf", "mse", "itae")


T = TypeVar("T")


def estimation_samples(result: FitResult) -> int:
    """Samples of a fit's estimation part(s), as :func:`information_criterion` counts them
    (0 when the fit does not say)."""
    data = result.settings.get("data") or {}
    # A fit of several records lists them (samples of each estimation part in "n").
    if isinstance(data, list):
        return int(sum(d.get("n", 0) for d in data))
    return int(data.get("n_est", 0))


def information_criterion(result: FitResult, kind: str = "bic") -> float:
    """BIC ``N ln(RSS/N) + k ln N`` or AIC ``N ln(RSS/N) + 2k`` on the estimation part.

    ``k`` counts the free parameters including the fitted initial state.
    """
    n = estimation_samples(result)
    mse = float(result.metrics["est"]["mse"])
    k = len(result.free)
    if not (mse > 0 and math.isfinite(mse)):
        return math.inf
    pen = k * math.log(n) if kind == "bic" else 2.0 * k
    if kind not in ("bic", "aic"):
        raise ParameterError(f"criterion must be 'bic' or 'aic', got {kind!r}")
    return n * math.log(mse) + pen


def noise_tolerance(n: int, z: float = NOISE_Z) -> float:
    """The tolerance of the noise level that ``n`` residual samples justify,
    ``sqrt(1 + z*sqrt(2/n)) - 1`` (0.068 for 400 samples, 0.040 for 1200).

    ``sqrt(2/n)`` is the relative standard error of the mean square of ``n`` white-noise
    samples; ``z`` of them is the excess of a residual's variance over its noise level that
    chance explains (measured spread of ``rmse^2 / noise_level^2`` on white noise, with the
    level estimated from the same samples: 0.055 at 400 samples, 0.028 at 1200, below the
    bound). Used in place of a flat :data:`NOISE_TOL` by the loop's default: a flat 15 %
    (32 % in variance, 5 standard errors on a 400-sample selection part) refused a true
    valve dead zone that removed 30 % of the noise variance after a friction had absorbed
    the rest (docs/diagnosis.md). What a stand-in gains by structural mismatch just above
    the noise is left to the margin of :func:`acceptance`.

    Parameters
    ----------
    n : int
        Residual samples the noise level and RMSE are estimated from (the selection part).
    z : float
        Standard errors granted.
    """
    if n < 1:
        raise ParameterError(f"noise_tolerance needs at least one sample, got n={n}")
    return math.sqrt(1.0 + z * math.sqrt(2.0 / n)) - 1.0


def noise_allowance(noise: float, noise_tol: float) -> float:
    """Selection variance that noise and structural mismatch explain,
    ``((1 + noise_tol)^2 - 1) * noise^2`` [output unit^2] (0 when ``noise`` is not finite).

    A candidate must remove more than this (:func:`acceptance`); two models whose
    selection variances differ by less are not told apart by the selection part.
    """
    return ((1 + noise_tol) ** 2 - 1) * noise ** 2 if math.isfinite(noise) else 0.0


def acceptance(rmse_before: float, rmse_after: float, crit_before: float, crit_after: float,
               margin: float, criterion: str = "bic", noise: float = math.nan,
               noise_tol: float = 0.0) -> tuple[bool, str]:
    """The loop's acceptance rule for a candidate (a library effect or a discovered term).

    Accepted when all three hold: the selection RMSE falls by ``margin``
    (``rmse_after <= (1 - margin) * rmse_before``) or to the noise level
    (``rmse_after <= noise``), the information criterion on
    estimation falls, and the variance removed exceeds what noise and structural
    mismatch allow, ``rmse_before^2 - rmse_after^2 > ((1 + noise_tol)^2 - 1) * noise^2``
    (a fixed margin alone let records from an independently written rig gain 10-15 %
    per effect just above the noise floor, docs/diagnosis.md; no allowance when ``noise``
    is not finite).

    Parameters
    ----------
    rmse_before, rmse_after : float
        Selection RMSE of the current model and of the candidate (output units).
    crit_before, crit_after : float
        Information criterion on estimation (:func:`information_criterion`).
    margin : float
        Required relative fall of the selection RMSE.
    criterion : str
        Name of the criterion (for the reason).
    noise : float
        Noise level of the selection residual (output units).
    noise_tol : float
        Tolerance of the noise allowance.

    Returns
    -------
    accepted : bool
    reason : str
        The three comparisons in words.
    """
    gain_ok, gain_text = _gain(rmse_before, rmse_after, margin, noise, noise_tol)
    crit_ok = crit_after < crit_before
    reason = (f"selection RMSE {gain_text}; {criterion.upper()} {crit_before:.1f} -> "
              f"{crit_after:.1f} ({'agrees' if crit_ok else 'disagrees'})")
    return gain_ok and crit_ok, reason


def _gain(rmse_before: float, rmse_after: float, margin: float, noise: float,
          noise_tol: float) -> tuple[bool, str]:
    """Whether an RMSE's fall is a gain, for :func:`acceptance` (the selection part's vote)
    and :func:`rotated_verdict` (the two folds'): by ``margin`` or to the noise level, and
    beyond the noise allowance; with ``"a -> b (...)"`` in words."""
    vr = rmse_after if math.isfinite(rmse_after) else math.inf
    # The margin asks for no more than the noise level: a candidate that takes the
    # selection residual to its noise has gained what can be gained (a true drag term from
    # a base that had absorbed most of it fell 9 % to below the noise level and was
    # refused, docs/diagnosis.md); the allowance still asks it to remove more than chance.
    reaches_noise = math.isfinite(noise) and vr <= noise
    clear = vr <= (1 - margin) * rmse_before
    text = ("clear gain" if clear else "to the noise level" if reaches_noise
            else f"gain below {100 * margin:.0f} %")
    # A model within (1 + noise_tol) of the noise explains everything an effect can
    # claim; a candidate must remove more selection variance than that allowance.
    allowance = noise_allowance(noise, noise_tol)
    beyond = rmse_before ** 2 - vr ** 2 > allowance
    return bool((clear or reaches_noise) and beyond), (
        f"{rmse_before:.4g} -> {vr:.4g} ({text}; {'beyond' if beyond else 'within'} the "
        f"noise allowance {math.sqrt(allowance):.3g})")


#: A deciding part holds a candidate's regime *thinly* when its share of the regime's
#: samples is below this fraction of its share of all samples (a part with a quarter of the
#: samples and under an eighth of the regime): such a part cannot refuse the candidate alone
#: (:func:`thin_part`).
REGIME_THIN = 0.5


def votes(rmse_before: float, rmse_after: float, crit_before: float, crit_after: float,
          margin: float, noise: float = math.nan, noise_tol: float = 0.0
          ) -> tuple[bool, bool]:
    """The two votes inside :func:`acceptance`: (the selection part's, the criterion's).

    The selection part votes for the candidate when its RMSE falls by ``margin`` (or to
    the noise level) and beyond the noise allowance; the criterion when it falls.
    """
    return (_gain(rmse_before, rmse_after, margin, noise, noise_tol)[0],
            bool(crit_after < crit_before))


#: A deciding part holding fewer samples of a candidate's regime than this cannot refuse
#: it alone, whatever its share (:func:`thin_parts`): on a short record a quarter of it may
#: hold the regime in proportion and still only in one or two events (a level reached once,
#: a few reversals), too few to tell the candidate's gain from the noise there.
REGIME_MIN_SAMPLES = 50


def regime_samples(regime: Mapping[str, Any], part: str) -> float:
    """Samples of a candidate's regime in ``part`` of a step's coverage (all of the part's
    samples where the coverage gives no ``in_regime``)."""
    return float(regime[part].get("samples", 0)) * float(regime[part].get("in_regime", 1.0))


def thin_parts(regime: Mapping[str, Any] | None) -> tuple[str, ...]:
    """The deciding parts (``"est"``, ``"sel"``) that hold the regime too thinly to refuse a
    candidate alone.

    ``regime`` is a step's coverage (:func:`hhra_phys.regime.regime_coverage` or
    :func:`hhra_phys.regime.change_coverage`). A part is thin when its ``share`` of the
    regime's samples is below :data:`REGIME_THIN` times its share of the samples, or when
    it holds fewer than :data:`REGIME_MIN_SAMPLES` samples of the regime (a short part).
    Empty when neither is (or the coverage is not known, or no part reaches the regime).
    """
    if not regime or "est" not in regime or "sel" not in regime:
        return ()
    n = {p: float(regime[p].get("samples", 0)) for p in ("est", "sel")}
    total = n["est"] + n["sel"]
    if total <= 0 or not any(regime[p].get("share", 0.0) > 0 for p in n):
        return ()
    return tuple(p for p in n
                 if regime[p].get("share", 0.0) < REGIME_THIN * n[p] / total
                 or regime_samples(regime, p) < REGIME_MIN_SAMPLES)


def thin_part(regime: Mapping[str, Any] | None) -> str | None:
    """The first of :func:`thin_parts` (``"est"`` before ``"sel"``), or ``None``."""
    thin = thin_parts(regime)
    return thin[0] if thin else None


def needs_rotation(sel_vote: bool, crit_vote: bool,
                   thin: str | Sequence[str] | None) -> bool:
    """Whether the parts rotate for a candidate: the selection part and the criterion on
    estimation disagree, and the part whose evidence says no is among the ``thin`` ones
    (:func:`thin_parts`): a part that barely reaches the regime cannot refuse alone.
    """
    if sel_vote == crit_vote or not thin:
        return False
    parts = (thin,) if isinstance(thin, str) else tuple(thin)
    return ("sel" if crit_vote else "est") in parts


def pooled_rmse(parts: Sequence[tuple[int, float]]) -> float:
    """The RMSE over parts of ``(samples, rmse)``, each weighted by its samples."""
    n = sum(k for k, _ in parts)
    if n <= 0:
        return math.nan
    return math.sqrt(sum(k * r * r for k, r in parts) / n)


def rotated_verdict(rmse_before: float, rmse_after: float, margin: float, noise: float,
                    noise_tol: float, k: int = 2) -> tuple[bool, str]:
    """The one verdict where the parts rotated: the held-out RMSE pooled over the folds.

    The two folds (fitted on estimation, scored on selection; fitted on selection, scored
    on estimation), or ``k`` contiguous blocks each held out in turn
    (:mod:`hhra_phys.diagnosis.folds`), see the whole regime between them, so their pooled
    error decides, by the same gain and allowance as :func:`acceptance`. The information
    criterion is not asked again: computed on the estimation part only, it is one of the
    two votes that disagreed, and one of the parts holds the regime thinly.

    Parameters
    ----------
    rmse_before, rmse_after : float
        Pooled held-out RMSE of the current model and of the candidate (output units).
    margin, noise, noise_tol : float
        As in :func:`acceptance`; ``noise`` the pooled noise level of the folds.
    k : int
        Folds pooled (for the reason's words).

    Returns
    -------
    accepted : bool
    reason : str
    """
    ok, text = _gain(rmse_before, rmse_after, margin, noise, noise_tol)
    over = "both folds" if k == 2 else f"{k} folds"
    return ok, f"held-out RMSE over {over} {text} decides"


@dataclass
class Step:
    """One candidate effect tried in the loop."""

    round: int
    effect: str
    evidence: dict[str, Any]
    params: dict[str, float]
    ci95: dict[str, list[float]]
    est: dict[str, float]
    val: dict[str, float]
    criterion: float
    criterion_before: float
    val_rmse_before: float
    accepted: bool = False
    reason: str = ""
    identifiable: bool = True
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0
    #: ``"add"``: a candidate proposed in a round (forward step); ``"keep"`` or
    #: ``"remove"``: the backward check of an effect accepted earlier (:func:`diagnose`'s
    #: ``backward``), where ``val_rmse_before``/``criterion_before`` are the model
    #: *without* the effect and ``val``/``criterion`` the model with it.
    action: str = "add"
    #: The backward check took the effect out of the model.
    removed: bool = False
    #: Where the candidate enters the model (``"input"``, ``"output"``, ``"rate:<state>"``,
    #: ``"mode:..."``; empty when it changes no equation).
    entry: str = ""
    #: The candidate describes the measurement (a sensor's offset or drift,
    #: :attr:`hhra_phys.parts.Effect.sensor`, or the input's inter-sample behaviour,
    #: :mod:`hhra_phys.intersample`), not the dynamics.
    sensor: bool = False
    #: How much of the candidate's regime each deciding part holds
    #: (:func:`hhra_phys.regime.regime_coverage`, or without a first-order column
    #: :func:`hhra_phys.regime.change_coverage`; ``None``: not measured). It decides only
    #: whether the parts rotate (:func:`needs_rotation`).
    regime: dict[str, Any] | None = None
    #: The rotated verdict (:func:`rotated_verdict`), where the parts rotated because one
    #: of them could not decide alone: ``k`` (folds), ``why``, the pooled two-fold RMSE
    #: ``rmse_before``/``rmse_after``, each part's ``est``/``sel`` as the held-out fold,
    #: ``noise`` and ``accepted``; ``None``: the parts did not rotate.
    folds: dict[str, Any] | None = None
    #: The effects refitted together in one candidate (``[first, second]``: the second is
    #: :attr:`effect`, the first a refused one the evidence contradicted, :func:`contradicts`,
    #: whose refit the pair starts from); empty for a candidate of one effect.
    pair: list[str] = field(default_factory=list)
    #: A term or mode discovery built (its shape was chosen from the data), not a library
    #: or user effect whose shape was given in advance.
    discovered: ClassVar[bool] = False

    def to_json(self) -> dict[str, Any]:
        """JSON-able dictionary (layout of the CLI's report)."""
        return {
            "round": self.round, "effect": self.effect, "evidence": self.evidence,
            "params": self.params, "ci95": self.ci95,
            "est": {k: self.est.get(k) for k in METRIC_KEYS},
            "val": {k: self.val.get(k) for k in METRIC_KEYS},
            "criterion": self.criterion, "criterion_before": self.criterion_before,
            "val_rmse_before": self.val_rmse_before, "accepted": self.accepted,
            "reason": self.reason, "identifiable": self.identifiable, "notes": self.notes,
            "seconds": self.seconds, "action": self.action, "removed": self.removed,
            "entry": self.entry, "sensor": self.sensor, "regime": self.regime,
            "folds": self.folds, "pair": list(self.pair),
        }


def judge(step: Step, rmse_cur: float, crit_cur: float, noise: float, margin: float,
          noise_tol: float, criterion: str = "bic") -> bool:
    """:func:`acceptance` of a refitted candidate against the current model; writes
    ``step.reason``.

    Parameters
    ----------
    step : Step
        The candidate (its ``val["rmse"]`` and ``criterion``).
    rmse_cur, crit_cur : float
        Selection RMSE (output units) and information criterion of the current model.
    noise, margin, noise_tol, criterion
        As in :func:`acceptance`.

    Returns
    -------
    bool
        Whether the candidate is acceptable.
    """
    ok, step.reason = acceptance(rmse_cur, float(step.val.get("rmse", math.inf)), crit_cur,
                                 step.criterion, margin, criterion, noise, noise_tol)
    return ok


def choose(candidates: Sequence[tuple[Step, T]], noise: float, noise_tol: float,
           criterion: str = "bic") -> tuple[Step, T]:
    """The winner among a round's acceptable candidates (one tie rule for every kind).

    The lowest selection RMSE wins, unless other candidates are within the noise
    allowance of it (``rmse^2 - best^2 <= noise_allowance(noise, noise_tol)``): the
    selection part cannot tell those apart, so the information criterion on estimation
    (``Step.criterion``) decides among them, the lowest wins; except that a discovered
    term tied with a given (library or user) effect at the same entry is not chosen over
    it (on a dead-zone record a discovered ``u += ... relu(u - c)`` tied with the library
    dead zone and won by BIC: the same physics, with a shape searched among many); and a
    sensor effect (``Step.sensor``) tied with candidates that change the dynamics is chosen
    over them unless a given (not discovered) one has a criterion lower by more than
    :data:`DECISIVE_CRITERION` (on a record with a drifting encoder a biased valve tied with
    the drift and won by 5 units of BIC: physics added for a sensor's fault,
    docs/measuring.md; on a two-tank record a true side inflow beat a level offset by 12.3).
    Measured on reference records (docs/diagnosis.md): among resonant modes the criterion
    chose the true one 6 of 6 times where the lowest selection error chose an input-mode
    stand-in once in 3.

    The winner's reason is prefixed ``"accepted: "`` and it is marked accepted; every other
    candidate's reason says why it was not chosen.

    Parameters
    ----------
    candidates : sequence of (Step, payload)
        Acceptable candidates (:func:`acceptance` said yes) with anything the caller needs
        back for the winner (its fit).
    noise : float
        Noise level of the current model's selection residual (output units).
    noise_tol : float
        Tolerance of the noise allowance.
    criterion : str
        Name of the criterion (for the reasons).

    Returns
    -------
    (Step, payload)
        The chosen candidate.
    """
    if not candidates:
        raise ParameterError("choose needs at least one acceptable candidate")

    def sel(s: Step) -> float:
        v = float(s.val.get("rmse", math.inf))
        return v if math.isfinite(v) else math.inf

    best = min(sel(s) for s, _ in candidates)
    allowance = noise_allowance(noise, noise_tol)
    tied = [c for c in candidates if _tied(sel(c[0]), best, allowance)]
    why_not = {id(c[0]): "a higher selection error" for c in candidates}
    level = "within the noise allowance of the best on selection"
    # At one entry, a given effect and a discovered term that the selection part cannot
    # tell apart are two descriptions of one missing piece: the effect whose shape was
    # known in advance is kept. The criterion charges the term's coefficients, not the
    # search over shapes that chose it from the data.
    given = {c[0].entry for c in tied if not c[0].discovered and c[0].entry}
    kept = [c for c in tied if not (c[0].discovered and c[0].entry in given)] or tied
    why_not.update({id(c[0]): f"{level}, a discovered term at the entry of a given effect"
                    for c in tied if all(c is not k for k in kept)})
    # A sensor's explanation tied with a change of the dynamics is kept: the record cannot
    # tell them apart (a drifting encoder and a biased valve leave the same trend), and
    # only the dynamics change would alter the model a controller is designed on. A prior,
    # so it yields to decisive evidence: a change of the dynamics whose criterion is lower
    # by more than DECISIVE_CRITERION (a two-tank side inflow against a level offset, 12.3).
    # Only a given change can be decisive: a discovered term's criterion charges its
    # coefficients, not the search over shapes (as above), and on a resonator read as
    # foh a three-term output feedthrough beat the right inter-sample behaviour by 17.7.
    sensors = [c for c in kept if c[0].sensor]
    given = [c for c in kept if not c[0].sensor and not c[0].discovered]
    if not sensors or (given and min(c[0].criterion for c in given)
                       < min(c[0].criterion for c in sensors) - DECISIVE_CRITERION):
        sensors = kept
    why_not.update({id(c[0]): f"{level}, a change of the dynamics tied with a sensor effect"
                    for c in kept if all(c is not k for k in sensors)})
    why_not.update({id(c[0]): f"{level}, higher {criterion.upper()}" for c in sensors})
    step, payload = min(sensors, key=lambda c: (c[0].criterion, sel(c[0])))
    step.accepted = True
    step.reason = "accepted: " + step.reason
    for other, _ in candidates:
        if other is not step:
            other.reason = (f"acceptable, not chosen ({why_not[id(other)]} than {step.effect})"
                            f": {other.reason}")
    return step, payload


def _tied(rmse: float, best: float, allowance: float) -> bool:
    """Whether the selection part cannot tell ``rmse`` from ``best`` (:func:`choose`)."""
    return rmse ** 2 - best ** 2 <= allowance


def tie_break(fits: Sequence[tuple[float, float]], noise: float, noise_tol: float,
              prefer: Sequence[bool] | None = None) -> int:
    """:func:`choose`'s tie rule for bare fits: the index of the one it would choose.

    Of ``(selection RMSE, information criterion)`` pairs, those within the noise allowance
    of the lowest selection RMSE are tied and the lowest criterion among them wins (the
    lowest RMSE breaks an exact tie). Used where one candidate has several fitted forms
    (discovery's variants of a term at one entry), so that they are told apart as
    candidates are. As :func:`choose` keeps a given effect over a discovered term it
    ties with at one entry, ``prefer`` marks fits kept over the others in a tie
    (discovery: forms in the state whose rate the term enters, the first-order
    equivalents in other variables are the model's own dynamics passing it on).

    Parameters
    ----------
    fits : sequence of (float, float)
        Selection RMSE (output units; non-finite counts as infinite) and criterion of each.
    noise, noise_tol : float
        As in :func:`choose`.
    prefer : sequence of bool, optional
        One per fit: the preferred among the tied fits, if any, are the only ones the
        criterion then decides between.
    """
    if not fits:
        raise ParameterError("tie_break needs at least one fit")
    if prefer is not None and len(prefer) != len(fits):
        raise ParameterError(f"tie_break: prefer has {len(prefer)} entries for "
                             f"{len(fits)} fits")
    sels = [v if math.isfinite(v) else math.inf for v, _ in fits]
    best = min(sels)
    allowance = noise_allowance(noise, noise_tol)
    tied = [i for i, v in enumerate(sels) if _tied(v, best, allowance)]
    if prefer is not None:
        tied = [i for i in tied if prefer[i]] or tied
    return min(tied, key=lambda i: (fits[i][1], sels[i]))


#: Most contradicted candidates (:func:`contradicts`) that start pairs when a round accepts
#: nothing: the two with the lowest criterion, each paired with every other refused effect
#: of the dynamics.
PAIR_CANDIDATES = 2


def contradicts(step: Step, rmse_cur: float, crit_cur: float) -> bool:
    """Whether the evidence on a refused effect contradicts itself the way two missing
    effects that need each other leave it: the criterion on estimation is decisively for
    it (lower by more than :data:`DECISIVE_CRITERION`) while the selection error *rose*.

    A missing effect that shows only beside another one leaves exactly this: on a drive
    with Coulomb friction and a constant force offset, each of the two (and a dead zone,
    an input offset) lowered the criterion on the estimation half by 4,000-12,600 units
    and raised the selection half's free-run error by 10-30 % (the position drifts where
    the other is missing), so no round accepted anything (docs/diagnosis.md). A candidate
    whose selection error merely fails the margin is not a contradiction, nor is a sensor
    effect (it describes the measurement: it cannot make a change of the dynamics show)
    or a discovered term (its shape was searched among many, so its criterion is not
    evidence of the same strength). When a round accepts nothing, the loop pairs such a
    candidate with the round's other refused effects, each pair one candidate judged by the
    one rule (:attr:`Step.pair`, :mod:`hhra_phys.diagnosis.pairs`).
    """
    rmse = float(step.val.get("rmse", math.inf))
    return (step.action == "add" and not step.sensor and not step.discovered
            and not step.accepted and math.isfinite(step.criterion)
            and step.criterion < crit_cur - DECISIVE_CRITERION
            and math.isfinite(rmse) and rmse > rmse_cur)


def round_settled(step: Step, noise_sel: float, noise_est: float, noise_tol: float,
                  accepted: bool) -> bool:
    """Whether an acceptable candidate leaves nothing for the rest of its round to win.

    True when ``step`` is acceptable and leaves both the selection and the estimation
    residual at the noise level, ``rmse <= (1 + noise_tol) * noise`` on each part with that
    part's noise level (measured on the current model). Why the rest of the round may be
    skipped: no model can bring a part below its noise level, so any later candidate's
    selection variance lies above ``noise^2`` and this one's at most
    ``(1 + noise_tol)^2 * noise^2``; the later one can therefore not beat this one by more
    than the noise allowance, and would at best tie with it. The tie would then go by the
    information criterion (:func:`choose`), which is the one decision skipping can change;
    the loop reports the skip (``Step`` notes and the progress lines).

    Parameters
    ----------
    step : Step
        A refitted candidate (``est`` and ``val`` hold its RMSE).
    noise_sel, noise_est : float
        Noise levels of the selection and estimation residuals (output units).
    noise_tol : float
        Tolerance of the noise level.
    accepted : bool
        Whether :func:`acceptance` accepted it (an unacceptable one settles nothing).
    """
    if not accepted or not (math.isfinite(noise_sel) and math.isfinite(noise_est)):
        return False
    lim = 1.0 + noise_tol
    return (float(step.val.get("rmse", math.inf)) <= lim * noise_sel
            and float(step.est.get("rmse", math.inf)) <= lim * noise_est)


def backward_decision(rmse_without: float, rmse_with: float, crit_without: float,
                      crit_with: float, noise: float, margin: float, noise_tol: float,
                      criterion: str = "bic") -> tuple[bool, str]:
    """Whether an effect accepted earlier is taken out again (the backward step).

    The forward rule read the other way: the effect stays only if it would be
    accepted when proposed now to the model without it, i.e. :func:`acceptance`
    with the model without it as "before" and the current model as "after". There
    is no second threshold.

    Parameters
    ----------
    rmse_without, rmse_with : float
        Selection RMSE of the model without the effect (refitted) and of the
        current model with it (output units).
    crit_without, crit_with : float
        Their information criteria on estimation (:func:`information_criterion`).
    noise : float
        Noise level of the selection residual of the model without it (output units).
    margin, noise_tol : float
        As in :func:`acceptance`.
    criterion : str
        Name of the criterion (for the reason).

    Returns
    -------
    remove : bool
        True when the effect would not be accepted now.
    reason : str
        :func:`acceptance`'s comparisons.
    """
    keep, reason = acceptance(rmse_without, rmse_with, crit_without, crit_with, margin,
                              criterion, noise, noise_tol)
    return not keep, reason


#: Ljung-Box p-value (over the residual's 40 lags) below which an estimation residual is
#: *clearly coloured*: then its RMSE within the noise allowance does not put it at the
#: noise level (:func:`stops_at_noise`). Why: the noise level is estimated as the part of
#: the residual not coherent with the input, and an effect the model lacks that is not
#: linear in the input (a seal friction) inflates it, so the ratio can pass while the
#: residual is still structured. Measured: true structures left estimation residuals
#: white (p 0.08-0.85; their selection parts, scored from a re-estimated state, down to
#: p 1e-7), where a cylinder lacking its friction left p 1e-15 at ratio 1.01 and a rig
#: lacking its quadratic drag p 4e-23 at 1.04 (docs/diagnosis.md).
COLOURED_P = 1e-6


def at_noise_level(level: Mapping[str, Any], noise_tol: float,
                   coloured_p: float = 0.0) -> bool:
    """Whether a residual (a :func:`selection_noise` dictionary) leaves nothing to model.

    At the noise level: white by Ljung-Box, or ``rmse <= (1 + noise_tol) * noise`` and not
    clearly coloured (Ljung-Box p at least ``coloured_p``; 0: any colour).
    """
    if level["white"]:
        return True
    return bool(level["ratio"] <= 1 + noise_tol
                and (coloured_p <= 0 or level["ljung_box_p"] >= coloured_p))


def stops_at_noise(level: Mapping[str, Any], noise_tol: float) -> bool:
    """The decision of :func:`noise_stop` from its ``level`` dictionary: the selection part
    and ``level["estimation"]`` are both at the noise level (:func:`at_noise_level`), the
    estimation part's residual not clearly coloured (:data:`COLOURED_P`)."""
    return (at_noise_level(level, noise_tol)
            and at_noise_level(level["estimation"], noise_tol, COLOURED_P))


def split_record(data: Dataset, split: float, test: float) -> tuple[Dataset, Dataset,
                                                                    Dataset | None]:
    """The loop's estimation, selection and test parts (in time order).

    Parameters
    ----------
    data : Dataset
        The whole record, N samples.
    split : float
        Fraction of N for estimation (the first ``round(split*N)`` samples).
    test : float
        Fraction of N held out at the end for the test part; 0 gives the old
        two-way split (selection = everything after estimation, no test part).

    Returns
    -------
    est, sel, test : Dataset, Dataset, Dataset or None
    """
    if not 0 < split < 1:
        raise ParameterError(f"split must be in (0, 1) so that selection data exist, got {split}")
    if not 0 <= test < 1 - split:
        raise ParameterError(
            f"test must be in [0, 1 - split) = [0, {1 - split:g}) so that selection data "
            f"exist, got {test}")
    est, rest = data.split(split)
    if test == 0:
        return est, rest, None
    n_test = int(round(test * data.n))
    if not 0 < n_test < rest.n:
        raise ParameterError(f"test={test} leaves no selection or no test samples in a "
                             f"{data.n}-sample record")
    sel, held = rest.split_at(rest.n - n_test)
    return est, sel, held
