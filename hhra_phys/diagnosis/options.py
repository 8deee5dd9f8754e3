"""The diagnosis loop's settings (:class:`LoopOptions`), validated as a whole.

Apart from the engine so that a user (and the CLI) can build and check them without
importing the fits.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from hhra_phys.diagnosis.folds import MAX_FOLDS
from hhra_phys.effects import (
    EFFECTS,
    effect_name,
)
from hhra_phys.errors import ParameterError
from hhra_phys.options import with_overrides

__all__ = ["LoopOptions", "SHAPE_MODES"]

#: Where the loop fits a smooth-edged library effect's shape (``LoopOptions.fit_shapes``):
#: the round's chosen effect, every contender's refit, or nowhere.
SHAPE_MODES = ("chosen", "contenders", "off")


#: IPOPT iteration limit of an accepted candidate's polish (the old loop's limit for
#: every candidate); the base fit keeps the plain fit's limit.
POLISH_ITER = 60


@dataclass(frozen=True)
class LoopOptions:
    """Settings of the diagnosis loop (:func:`diagnose`), validated as a whole.

    Every field is also a keyword of :func:`diagnose`, which overrides the options it is
    given (``diagnose(ds, options=LoopOptions(seed=3), max_effects=2)``).

    Attributes
    ----------
    split : float
        Estimation fraction of the whole record (default 0.5).
    test : float
        Fraction held out at the end as the test part (default 0.25): it chooses
        nothing and only reports the base and final models' error
        (:attr:`DiagnosisResult.test`). ``0`` restores the old two-way split, where the
        part after estimation both selects and reports (optimistic).
    candidates : sequence of str, optional
        Library effects that may be added (default: all registered; ``[]``: none, so
        that discovery alone proposes).
    max_effects : int
        Most additions (library effects, user effects, discovered terms and modes alike);
        0 adds nothing. Default 4: three library effects and one discovered term, what the
        loop could add when discovery ran once after the library (the public record needs
        all four: asymmetric valve, delay, saturation and a load mode, docs/diagnosis.md).
    top_k : int, optional
        Library candidates refitted per round, best ranked first. Default: all of them
        (until one settles the round, :func:`~hhra_phys.diagnosis.selection.round_settled`).
        The ranking orders and explains; refits decide (a first-order ranking put the
        effect that paid most far down on the public record, docs/diagnosis.md).
    pop_size, max_iter : int
        Global search of the base fit (default 100 x 200, as :func:`~hhra_phys.fit.fit`:
        a loop is only as good as its base: a smaller base search left every candidate
        judged against a weak base, docs/diagnosis.md).
    cand_pop, cand_iter : int, optional
        Global search over a candidate's new parameters (default: sized to their
        number, ``8 + 4*n_new`` points for ``10 + 5*n_new`` iterations).
    seed : int
        Seed of every global search.
    margin : float
        Required relative fall of the selection RMSE (0.1: at least 10 %), unless it
        falls to the selection residual's noise level
        (:func:`~hhra_phys.diagnosis.selection.acceptance`).
    noise_tol : float, optional
        Tolerance of the noise level: the loop stops when the selection RMSE is
        within ``(1 + noise_tol)`` of the selection residual's noise level (or that
        residual is white), and a candidate must remove more selection variance than
        ``((1 + noise_tol)^2 - 1) * noise^2``. Default: what the selection part's length
        justifies, :func:`~hhra_phys.diagnosis.selection.noise_tolerance` (0.068 for 400 samples);
        a number gives a flat allowance (:data:`NOISE_TOL` = 0.15 was the default until
        2026-11-25, ``docs/diagnosis.md``).
    criterion : {"bic", "aic"}
        Information criterion on the estimation part that must also fall.
    free : sequence of str, optional
        Free base parameters (default: the Problem's default).
    bounds : dict, optional
        Bounds overriding the model's (base and effect parameters); never widened.
    default_bounds : dict, optional
        Boxes replacing the model's defaults (e.g. scaled to a record in sample
        units, :func:`base_model_for`): like the model's own, widened by decades when
        a fitted group ends at an edge (:mod:`hhra_phys.fit`), unlike ``bounds``.
    effect_kw : dict, optional
        ``{effect: {field: value}}`` for :func:`~hhra_phys.effects.make_effect`.
    backend : {"auto", "native", "casadi"}
        Simulator backend: compiled native code by default (the compiled-code cache
        is keyed by the generated code, so a model structure compiles once per
        machine), CasADi's virtual machine without a compiler.
    ipopt_iter : int
        IPOPT iteration limit of a candidate's refinement. 20 iterations judged five
        HHRA candidates as well as 60 but left the two-tank example's side inflow
        unconverged (selection RMSE 0.0518 against 0.0510), so that a stand-in won;
        the default stays 60. The accepted candidate is polished again
        (:data:`POLISH_ITER`).
    initial_state : {"fit", "data", "zero"}
        Initial-state rule of every fit (:mod:`hhra_phys.problem`).
    background : bool
        Without an executor, compile the next candidates' simulators in a
        background thread while the current one is refitted (default True).
    discover : bool
        In every round, beside the library's effects, propose terms and modes outside the
        library (:class:`hhra_phys.diagnosis.discovery.Discovery`): ranked with the effects by
        first-order score, refitted and judged by the same rule (default True). With
        several records they are screened on the record with the largest residual and
        fitted to all.
    discover_kw : dict, optional
        Options of :class:`~hhra_phys.diagnosis.discovery.Discovery` (``method``, ``max_terms``,
        ``entries``).
    joint_search : bool
        A candidate's global search also covers the parameters of the effects
        accepted in earlier rounds, instead of holding them at the previous fit
        (default False: held). An effect fitted alone can absorb part of the next one
        (a dead zone grown to mimic a sharp friction) and hold the refit in that
        local minimum; on 10 pair records the joint search found one such pair more
        but accepted one stand-in more (spool lag for a delay), so it is off by
        default (docs/diagnosis.md, "Simulated study").
    backward : bool
        Backward step (stepwise selection): after a round accepts an effect and at
        least two are in, each effect accepted earlier is refitted out of the model
        and removed when it would not be accepted if proposed now
        (:func:`backward_decision`, the same rule read the other way). A removed
        effect is not proposed again; rounds go on until ``max_effects`` are in, so
        a loop may run more rounds than ``max_effects``. Each check is a
        :class:`Step` with ``action`` ``"keep"`` or ``"remove"``.
    revisit : bool
        Revisit the one greedy choice a searched shape won over a given mechanism: when a
        round accepted a discovered term or mode over an acceptable given (library or
        user) effect and the loop then ends above the noise level, the path from that
        effect is followed too (from the same round, by the same rounds and rule), and
        the final model of each path is compared by the rule of
        :func:`~hhra_phys.diagnosis.selection.choose` (selection RMSE; within the noise allowance,
        the information criterion). The first such round is revisited, once. On the public
        record a two-term input stand-in took round 1 from the asymmetric valve and the
        loop stopped at 7.4 x the noise (docs/diagnosis.md). Not when the discovered
        candidate is no longer in the final model and that model holds given effects of
        the dynamics only (no discovered term or mode, no sensor effect: the backward step
        or a library form undid the greedy choice on this path;
        ``settings["revisit_skipped"]`` says so).
        ``settings["revisited"]`` says what ran and which path was kept.
    intersample : bool
        After the base fit and in every round (one record), while the record's own
        behaviour holds, when the current fit's residual carries the signature of the
        wrong inter-sample behaviour (:func:`hhra_phys.intersample.hold_suspected`: a
        sub-sample shift, or the curvature a straight line leaves under a smooth input,
        which shows only once the model's own error is below it), refit the same model
        with each other one (:func:`~hhra_phys.intersample.refit_with_hold`) and judge
        each by the same rule (:mod:`hhra_phys.diagnosis.selection`) beside the round's other
        candidates; the one :func:`~hhra_phys.diagnosis.selection.choose` picks is kept (tied, it is
        preferred like a sensor effect: it describes the measurement), and every later fit
        and score uses it. Each is a :class:`Step` named ``"intersample:<kind>"`` marked
        ``sensor``, which changes no physics, adds no parameter and no effect; a path
        changes the behaviour once.
    budget : float, optional
        Wall-clock seconds the loop may take (default: no limit). Checked before every
        round and every candidate's refit: once spent, the round refits nothing more,
        chooses among what it refitted, and the loop ends at the best model so far (no
        backward step, no revisit); ``settings["stopped_by_budget"]`` and a warning say
        so, with what was not refitted. The base fit always runs whole; the estimate
        printed after it says how long a round may take.
    progress_bar : bool
        A progress bar per round on standard error, naming the candidate being refitted
        and how many remain (shown on a terminal only; the CLI turns it on).
    fit_shapes : {"chosen", "contenders", "off"} or bool
        Fit the switching width of a library effect with a smooth edge (Coulomb
        friction's ``v_switch``, a backlash's ``w_contact``) where a sharper one fits
        better, and a friction's sign profile (algebraic or tanh) with it
        (:func:`_sharpen`; CLI ``--shapes MODE``, ``--fit-shapes`` for ``"contenders"``).
        ``"chosen"`` (default): the round's chosen effect, once accepted and after the
        backward step, so the shape never decides which effect wins a round (and effects
        accepted earlier whose width is still the default, again after each later
        acceptance); ``"contenders"`` (``True``): every
        contender in its refit, before the round is decided (a library friction whose
        default width loses to its sharper discovered twin can then win); ``"off"``
        (``False``): the library's default widths. Why not contenders by default: on
        the one-loop study's record of an exact dead zone beside an exact friction (seed
        1) the sharpened friction took round 1 from the dead zone and absorbed it, where
        the default width leaves both to be named; on a 1 kHz drive whose friction
        switches within 1e-4 m/s the sharpened width is what names the friction
        (docs/diagnosis.md).
    pairs : bool
        Refit pairs when a round accepts nothing (default True; CLI ``--no-pairs``): each
        of the two refused effects of the dynamics with the lowest criterion on which the
        criterion and the selection part contradict each other
        (:func:`~hhra_phys.diagnosis.selection.contradicts`: the criterion decisively for,
        the selection error up) is paired with every other refused effect of the dynamics,
        the second added to the first one's refit with both searched; each pair is a
        candidate judged by the one rule (``steps[].pair``, :mod:`hhra_phys.diagnosis.pairs`);
        an accepted pair adds both effects.
        Two effects that each show only beside the other (a drive's Coulomb friction and
        constant force) are otherwise never accepted.
    rotate : bool
        Rotate the parts where one cannot decide alone (default True; CLI
        ``--no-rotate``): when the selection part and the information criterion on
        estimation disagree on a candidate and the part that says no holds the candidate's
        regime thinly (:func:`~hhra_phys.diagnosis.selection.needs_rotation`; the regime of
        :func:`~hhra_phys.regime.regime_coverage`, or for a candidate without a
        first-order column of :func:`~hhra_phys.regime.change_coverage`), the candidate
        and the current model are refitted on the selection part and scored on the
        estimation part, and the held-out error pooled over both folds decides
        (:func:`~hhra_phys.diagnosis.selection.rotated_verdict`; ``steps[].folds``). The model
        itself stays fitted on estimation. Rotation also happens where the part that says
        no holds fewer than :data:`~hhra_phys.diagnosis.selection.REGIME_MIN_SAMPLES`
        samples of the regime (a short record: too few to refuse alone).
    folds : int
        Contiguous folds of a rotation (default 2; CLI ``--folds``): the selection part is
        one, the estimation part is cut into ``folds - 1`` blocks, each held out in turn
        with the model refitted on the rest of its record
        (:mod:`hhra_phys.diagnosis.folds`). 2 is the two-fold swap above; more folds
        cost ``folds - 1`` refits of the current model and of the candidate per rotation.
    """

    split: float = 0.5
    test: float = 0.25
    candidates: tuple[str, ...] | None = None
    max_effects: int = 4
    top_k: int | None = None
    pop_size: int = 100
    max_iter: int = 200
    cand_pop: int | None = None
    cand_iter: int | None = None
    seed: int = 0
    margin: float = 0.1
    noise_tol: float | None = None
    criterion: str = "bic"
    free: tuple[str, ...] | None = None
    bounds: Mapping[str, tuple[float, float]] | None = None
    default_bounds: Mapping[str, tuple[float, float]] | None = None
    effect_kw: Mapping[str, Mapping[str, Any]] | None = None
    backend: str = "auto"
    ipopt_iter: int = 60
    initial_state: str = "fit"
    background: bool = True
    discover: bool = True
    discover_kw: Mapping[str, Any] | None = None
    joint_search: bool = False
    backward: bool = True
    revisit: bool = True
    intersample: bool = True
    budget: float | None = None
    progress_bar: bool = False
    fit_shapes: bool | str = "chosen"
    rotate: bool = True
    pairs: bool = True
    folds: int = 2

    @property
    def shape_mode(self) -> str:
        """:attr:`fit_shapes` as one of :data:`SHAPE_MODES` (``True``: ``"contenders"``,
        ``False``: ``"off"``)."""
        if isinstance(self.fit_shapes, bool):
            return "contenders" if self.fit_shapes else "off"
        return str(self.fit_shapes)

    def validate(self) -> LoopOptions:
        """Check every setting; returns ``self``.

        Raises
        ------
        ParameterError
            Naming the setting and what is wrong with it.
        """
        def need(ok: bool, text: str) -> None:
            if not ok:
                raise ParameterError(text)

        need(self.criterion in ("bic", "aic"),
             f"criterion must be 'bic' or 'aic', got {self.criterion!r}")
        need(0 <= self.margin < 1, f"margin must be in [0, 1), got {self.margin}")
        need(self.noise_tol is None or self.noise_tol >= 0,
             f"noise_tol must be >= 0, got {self.noise_tol}")
        need(self.budget is None or (isinstance(self.budget, (int, float))
                                     and not isinstance(self.budget, bool)
                                     and math.isfinite(self.budget) and self.budget > 0),
             f"budget must be a number of seconds > 0, got {self.budget!r}")
        need(isinstance(self.fit_shapes, bool) or self.fit_shapes in SHAPE_MODES,
             f"fit_shapes must be one of {', '.join(map(repr, SHAPE_MODES))} (or True for "
             f"'contenders', False for 'off'), got {self.fit_shapes!r}")
        need(isinstance(self.rotate, bool), f"rotate must be True or False, got {self.rotate!r}")
        need(isinstance(self.pairs, bool), f"pairs must be True or False, got {self.pairs!r}")
        need(isinstance(self.folds, int) and not isinstance(self.folds, bool)
             and 2 <= self.folds <= MAX_FOLDS,
             f"folds must be an integer from 2 to {MAX_FOLDS}, got {self.folds!r}")
        need(isinstance(self.max_effects, int) and self.max_effects >= 0,
             f"max_effects must be an integer >= 0, got {self.max_effects!r}")
        need(self.top_k is None or (isinstance(self.top_k, int) and self.top_k >= 1),
             f"top_k must be an integer >= 1 or None, got {self.top_k!r}")
        for name in ("pop_size", "max_iter", "ipopt_iter"):
            v = getattr(self, name)
            need(isinstance(v, int) and v >= 1, f"{name} must be an integer >= 1, got {v!r}")
        for name in ("cand_pop", "cand_iter"):
            v = getattr(self, name)
            need(v is None or (isinstance(v, int) and v >= 1),
                 f"{name} must be an integer >= 1 or None, got {v!r}")
        need(self.backend in ("auto", "native", "casadi"),
             f"backend must be 'auto', 'native' or 'casadi', got {self.backend!r}")
        need(self.initial_state in ("fit", "data", "zero"),
             f"initial_state must be 'fit', 'data' or 'zero', got {self.initial_state!r}")
        bad_kw = sorted(set(self.discover_kw or {}) - {"method", "max_terms", "entries"})
        need(not bad_kw, f"discover_kw: unknown option(s) {', '.join(bad_kw)}; options: "
             "method, max_terms, entries")
        unknown = [n for n in (self.candidates or ()) if n not in EFFECTS]
        need(not unknown, f"unknown effect {unknown[0]!r}; library: {', '.join(EFFECTS)}"
             if unknown else "")
        return self

    @classmethod
    def of(cls, options: LoopOptions | None = None, **overrides: Any) -> LoopOptions:
        """``options`` (default: the defaults) with ``overrides`` applied, validated.

        Raises
        ------
        ParameterError
            An override that is not a setting (with the settings' names), or a bad value.
        """
        if "stop_on" in overrides:
            raise ParameterError(
                "stop_on was removed (its 'selection' rule stopped on the selection part "
                "alone): the loop stops when both the estimation and the selection parts "
                "are at the noise level (noise_stop); drop the setting")
        opts = with_overrides(options if options is not None else cls(), overrides, "loop",
                              ("candidates", "free"))
        if opts.candidates is not None:  # generic aliases (input_deadzone, ...) name the
            # same library parts: each is tried once
            opts = replace(opts, candidates=tuple(dict.fromkeys(
                effect_name(n) for n in opts.candidates)))
        return opts.validate()
