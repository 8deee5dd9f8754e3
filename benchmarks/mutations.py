"""Mutation check: does the test suite notice a plausible bug? (not a test; stdlib only)

Each :class:`Mutation` replaces one exact code fragment of the package by a wrong variant. For
every mutation the repository is copied to a temporary directory, the fragment is replaced
there, and ``python -m pytest -x -q <tests>`` runs in the copy with ``PYTHONPATH`` pointing at
it. A failing test run *kills* the mutation; a passing one means it *survived* (the tests did
not notice the bug). A fragment that does not occur exactly once in ``hhra_phys/`` is an
*error* of this list, never counted as a survival. Fragments are looked up by content, not by
file name, so the list survives files being moved::

    python benchmarks/mutations.py --list
    python benchmarks/mutations.py                       # every mutation
    python benchmarks/mutations.py --only hgwo-no-de-step metrics-mse-sum
    python benchmarks/mutations.py --group optim metrics --json out/mutations.json

Before the mutations, the tests named by the selected mutations run once on an unmutated copy:
if they fail there, every mutation would look killed, so the script stops.

Exit status: 0 if every mutation run was killed, 1 if some survived, 2 on errors.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "hhra_phys"
#: What is not copied: version control, virtual environments, outputs and caches.
IGNORE = shutil.ignore_patterns(
    ".git", ".venv*", "out", "__pycache__", ".pytest_cache", ".ruff_cache", "*.egg-info"
)

OPTIM_TESTS = ("tests/unit/test_optim_steps.py",)
METRICS_TESTS = ("tests/unit/test_metrics.py", "tests/unit/test_metrics_hand.py")
MODEL_TESTS = ("tests/unit/test_model.py", "tests/unit/test_simulate.py",
               "tests/integration/test_reference_rig.py")
EFFECT_TESTS = ("tests/unit/test_effects.py", "tests/integration/test_reference_rig.py")
EDGE_TESTS = ("tests/integration/test_sharp_edges.py", "tests/unit/test_effect_signatures.py")
LOOP_TESTS = ("tests/unit/test_loop_rule.py", "tests/integration/test_user_model.py",
              "tests/integration/test_diagnose.py")
RELIAB_TESTS = ("tests/unit/test_units.py", "tests/unit/test_cli_args.py",
                "tests/integration/test_bad_inputs.py")
DISCOVER_TESTS = ("tests/integration/test_discover.py",)
#: The mode's equation checks come first in the file, so -x stops there.
MODE_TESTS = "tests/integration/test_discover_mode.py"
#: Its slow rate test comes last, so -x stops at the quick test that notices.
MULTI_TEST = "tests/integration/test_multi_diagnose.py"
PROBLEM_TESTS = ("tests/integration/test_user_model.py", "tests/integration/test_cylinder.py",
                 "tests/integration/test_fit.py")


@dataclass(frozen=True)
class Mutation:
    """One deliberate bug.

    Attributes
    ----------
    id : str
        Short unique name, ``<group>-<what>``; the group is the part before the first ``-``.
    description : str
        The bug in words (what a developer could plausibly have written).
    snippet : str
        Exact code fragment that must occur exactly once in ``hhra_phys/``.
    replacement : str
        The mutated fragment.
    tests : tuple of str
        Test paths, relative to the repository, that should kill the mutation.
    """

    id: str
    description: str
    snippet: str
    replacement: str
    tests: tuple[str, ...]

    @property
    def group(self) -> str:
        """``optim``, ``metrics``, ``model`` ... (the id's first part, with the method names
        of the optimisers folded into ``optim``)."""
        head = self.id.split("-", 1)[0]
        return "optim" if head in {"hgwo", "gwo", "pso", "de", "optim"} else head


def _m(
    id: str, description: str, snippet: str, replacement: str, tests: tuple[str, ...]
) -> Mutation:
    return Mutation(id, description, snippet, replacement, tests)


MUTATIONS: tuple[Mutation, ...] = (
    # -- H-GWO's hybrid part (the four mutations that survived the original suite) ------------
    _m(
        "hgwo-de-r1-twice",
        "DE difference X_r1 - X_r1 (r1 used twice): the mutant is lam*alpha only",
        "self.F * (x[r[:, 0]] - x[r[:, 1]])",
        "self.F * (x[r[:, 0]] - x[r[:, 0]])",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-crossover-swapped",
        "crossover arguments swapped: the moved wolf acts as mutant and vice versa",
        "binomial_crossover(rng, mutant, moved, self.Cr)",
        "binomial_crossover(rng, moved, mutant, self.Cr)",
        OPTIM_TESTS,
    ),
    _m(
        "optim-crossover-forced-index-0",
        "forced crossover component always j = 0 instead of a random R",
        "take[np.arange(n), (u[:, d + 1] * d).astype(np.intp)] = True",
        "take[np.arange(n), 0] = True",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-no-de-step",
        "DE step removed: trial = moved wolf",
        "trial = self.box.redraw(binomial_crossover(rng, mutant, moved, self.Cr), rng)",
        "trial = moved",
        OPTIM_TESTS,
    ),
    # -- H-GWO: mutation, selection, initialisation ---------------------------------------------
    _m(
        "hgwo-mutation-uses-beta",
        "mutation built on beta instead of alpha",
        "mutant = self.lam * self.leaders[0]",
        "mutant = self.lam * self.leaders[1]",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-lam-ignored",
        "lambda dropped from the mutation (lam = 1 whatever the option)",
        "mutant = self.lam * self.leaders[0]",
        "mutant = self.leaders[0]",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-alpha-not-excluded",
        "r1, r2 may be alpha's index",
        "r = distinct_indices(rng, n, 2, exclude=alpha_idx)",
        "r = distinct_indices(rng, n, 2)",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-greedy-inverted",
        "greedy selection keeps the worse of trial and target",
        "win = trial_cost <= tgt_cost",
        "win = trial_cost >= tgt_cost",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-greedy-strict",
        "greedy selection: a tie keeps the target (paper eq. 23: the trial wins ties)",
        "win = trial_cost <= tgt_cost",
        "win = trial_cost < tgt_cost",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-previous-target-is-trial",
        "target_vector='previous' compares the trial with itself",
        "tgt, tgt_cost = self.population, self.costs",
        "tgt, tgt_cost = points, costs",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-a-schedule-shifted",
        "H-GWO's move uses a(t+1) instead of a(t) (a starts below 2)",
        "gwo_move(x, self.leaders, gwo_a(self.nit, self.max_iter), rng)",
        "gwo_move(x, self.leaders, gwo_a(self.nit + 1, self.max_iter), rng)",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-opposition-wrong",
        "opposite point hi - x instead of lo + hi - x",
        "return self.lower + self.upper - x",
        "return self.upper - x",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-tent-map-branch",
        "tent map's second branch divided by phi instead of 1 - phi",
        "x = np.where(x < phi, x / phi, (1.0 - x) / (1.0 - phi))",
        "x = np.where(x < phi, x / phi, (1.0 - x) / phi)",
        OPTIM_TESTS,
    ),
    _m(
        "hgwo-init-no-selection",
        "initial pack = the tent points, the opposites never selected",
        "pop, cst = best_distinct(points, costs, n)",
        "pop, cst = points[:n], costs[:n]",
        OPTIM_TESTS,
    ),
    _m(
        "optim-duplicates-kept",
        "best_distinct keeps duplicate points",
        "dup = (same & _strictly_upper(m)).any(axis=0)",
        "dup = np.zeros(m, dtype=bool)",
        OPTIM_TESTS,
    ),
    _m(
        "optim-bounds-clip-not-redraw",
        "eq. 22 broken: out-of-box components clipped instead of re-drawn",
        "x[rows, cols] = self.lower[cols] + rng.random(rows.size) * self.width[cols]",
        "x[rows, cols] = np.clip(x[rows, cols], self.lower[cols], self.upper[cols])",
        OPTIM_TESTS,
    ),
    _m(
        "optim-crossover-rate",
        "Cr = rand instead of 0.5*(1 + rand)",
        "rate = 0.5 * (1.0 + u[:, d : d + 1]) if cr is None else cr",
        "rate = u[:, d : d + 1] if cr is None else cr",
        OPTIM_TESTS,
    ),
    _m(
        "optim-crossover-fixed-cr-ignored",
        "a fixed Cr option is ignored (always the random paper rate)",
        "rate = 0.5 * (1.0 + u[:, d : d + 1]) if cr is None else cr",
        "rate = 0.5 * (1.0 + u[:, d : d + 1])",
        OPTIM_TESTS,
    ),
    # -- GWO move (shared by GWO and H-GWO) -----------------------------------------------------
    _m(
        "gwo-a-schedule",
        "a = 2 - t/MaxIter (ends at 1 instead of 0)",
        "return 2.0 - 2.0 * t / max(horizon, 1)",
        "return 2.0 - t / max(horizon, 1)",
        OPTIM_TESTS,
    ),
    _m(
        "gwo-A-range",
        "A = a*r1 - a (in [-a, 0]) instead of 2a*r1 - a",
        "step *= 2.0 * a",
        "step *= a",
        OPTIM_TESTS,
    ),
    _m(
        "gwo-C-factor",
        "C = r2 instead of 2*r2",
        "dist *= 2.0  # C",
        "dist *= 1.0  # C",
        OPTIM_TESTS,
    ),
    _m(
        "gwo-leaders-mixed",
        "alpha/beta/delta mixed up: D_alpha = |C*X_delta - X| and so on",
        "dist *= leaders[:, None, :]",
        "dist *= leaders[::-1, None, :]",
        OPTIM_TESTS,
    ),
    _m(
        "gwo-alpha-only",
        "X(t+1) = X1 (alpha) instead of (X1 + X2 + X3)/3",
        "return (leaders.sum(axis=0) - step.sum(axis=0)) / 3.0",
        "return leaders[0] - step[0]",
        OPTIM_TESTS,
    ),
    _m(
        "gwo-no-clip",
        "GWO's moved wolves not brought back into the box",
        "return self.box.clip(gwo_move(self.population, self.leaders, a, self.rng))",
        "return gwo_move(self.population, self.leaders, a, self.rng)",
        OPTIM_TESTS,
    ),
    _m(
        "gwo-leaders-not-persistent",
        "GWO's leaders taken from the current pack only (forgets better old points)",
        "self.leaders, self.leader_costs, points, costs",
        "None, None, points, costs",
        OPTIM_TESTS,
    ),
    _m(
        "optim-leaders-early-exit",
        "leaders left unchanged unless alpha is beaten (a new beta/delta is ignored)",
        "if costs.min() >= leader_costs[-1]:",
        "if costs.min() >= leader_costs[0]:",
        OPTIM_TESTS,
    ),
    # -- PSO --------------------------------------------------------------------------------------
    _m(
        "pso-no-inertia",
        "inertia weight dropped (w = 1)",
        "self.inertia(self.nit) * self.velocity",
        "self.velocity",
        OPTIM_TESTS,
    ),
    _m(
        "pso-inertia-schedule",
        "decreasing inertia reaches w_end one move late",
        "frac = t / max(self.max_iter - 1, 1)",
        "frac = t / max(self.max_iter, 1)",
        OPTIM_TESTS,
    ),
    _m(
        "pso-no-velocity-clamp",
        "velocity not clamped to [-vmax, vmax]",
        "self.velocity = np.clip(v, -self.vmax, self.vmax)",
        "self.velocity = v",
        OPTIM_TESTS,
    ),
    _m(
        "pso-c1-c2-swapped",
        "cognitive term weighted by c2",
        "self.c1 * r[0] * (self.pbest - x)",
        "self.c2 * r[0] * (self.pbest - x)",
        OPTIM_TESTS,
    ),
    _m(
        "pso-gbest-wrong",
        "social term pulls toward particle 0's personal best instead of the global best",
        "self.c2 * r[1] * (self.x_best - x)",
        "self.c2 * r[1] * (self.pbest[0] - x)",
        OPTIM_TESTS,
    ),
    _m(
        "pso-pbest-inverted",
        "personal best replaced by a worse point",
        "better = costs < self.pbest_costs",
        "better = costs > self.pbest_costs",
        OPTIM_TESTS,
    ),
    _m(
        "pso-pbest-ties",
        "personal best replaced on a tie (the convention: ties keep the earlier point)",
        "better = costs < self.pbest_costs",
        "better = costs <= self.pbest_costs",
        OPTIM_TESTS,
    ),
    # -- DE ---------------------------------------------------------------------------------------
    _m(
        "de-r2-twice",
        "DE difference X_r2 - X_r2: the mutant is X_r1",
        "self.F * (x[r[:, 1]] - x[r[:, 2]])",
        "self.F * (x[r[:, 1]] - x[r[:, 1]])",
        OPTIM_TESTS,
    ),
    _m(
        "de-self-not-excluded",
        "r1, r2, r3 may be the member itself",
        "r = distinct_indices(self.rng, n, 3, exclude=np.arange(n))",
        "r = distinct_indices(self.rng, n, 3)",
        OPTIM_TESTS,
    ),
    _m(
        "de-crossover-swapped",
        "DE crossover arguments swapped",
        "binomial_crossover(self.rng, mutant, x, self.Cr)",
        "binomial_crossover(self.rng, x, mutant, self.Cr)",
        OPTIM_TESTS,
    ),
    _m(
        "de-greedy-inverted",
        "DE keeps the worse of trial and target",
        "win = costs <= self.costs",
        "win = costs >= self.costs",
        OPTIM_TESTS,
    ),
    _m(
        "de-greedy-strict",
        "DE: a tie keeps the target",
        "win = costs <= self.costs",
        "win = costs < self.costs",
        OPTIM_TESTS,
    ),
    # -- metrics ----------------------------------------------------------------------------------
    _m(
        "metrics-mse-sum",
        "MSE without the mean (sum of squared errors)",
        "value = np.mean((yy - yh) ** 2, axis=-1)",
        "value = np.sum((yy - yh) ** 2, axis=-1)",
        METRICS_TESTS,
    ),
    _m(
        "metrics-mse-no-square",
        "MSE as printed in the paper's eq. 31: mean error, no square",
        "value = np.mean((yy - yh) ** 2, axis=-1)",
        "value = np.mean(yy - yh, axis=-1)",
        METRICS_TESTS,
    ),
    _m(
        "metrics-rmse-no-root",
        "RMSE returns the MSE",
        "return float(np.sqrt(value)) if isinstance(value, float) else np.sqrt(value)",
        "return value",
        METRICS_TESTS,
    ),
    _m(
        "metrics-vaf-mse",
        "VAF with the mean squared error in place of the error variance",
        "np.var(yy - yh, axis=-1) / var_y",
        "np.mean((yy - yh) ** 2, axis=-1) / var_y",
        METRICS_TESTS,
    ),
    _m(
        "metrics-vaf-var-yhat",
        "VAF with var(yhat) in place of var(y - yhat)",
        "np.var(yy - yh, axis=-1) / var_y",
        "np.var(yh, axis=-1) / var_y",
        METRICS_TESTS,
    ),
    _m(
        "metrics-itae-no-time-weight",
        "ITAE without the time weight (an IAE)",
        "weight = np.arange(n) * step",
        "weight = np.ones(n) * step",
        METRICS_TESTS,
    ),
    _m(
        "metrics-itae-off-by-one",
        "ITAE time weight starts at dt instead of 0",
        "weight = np.arange(n) * step",
        "weight = np.arange(1, n + 1) * step",
        METRICS_TESTS,
    ),
    _m(
        "metrics-itae-absolute-time",
        "ITAE weighted by absolute time, not time since the record's start",
        "weight = tt - tt[0]",
        "weight = tt",
        METRICS_TESTS,
    ),
    _m(
        "metrics-itae-no-dt",
        "ITAE sum not multiplied by dt",
        "value = np.sum(weight * np.abs(yy - yh), axis=-1) * step",
        "value = np.sum(weight * np.abs(yy - yh), axis=-1)",
        METRICS_TESTS,
    ),
    _m(
        "metrics-fit-scale",
        "FIT normalised by std(y) instead of ||y - mean(y)||",
        'np.sqrt(_spread(yy, "FIT") * yy.size)',
        'np.sqrt(_spread(yy, "FIT"))',
        METRICS_TESTS,
    ),
    _m(
        "metrics-max-abs-signed",
        "max error without the absolute value",
        "value = np.max(np.abs(yy - yh), axis=-1)",
        "value = np.max(yy - yh, axis=-1)",
        METRICS_TESTS,
    ),
    # -- model ----------------------------------------------------------------------------------
    _m(
        "model-orifice-sign-of-p",
        "orifice law takes the sign of the pressure instead of the valve current",
        "drop = 1 - smooth_sign(cmd, sign_eps) * p",
        "drop = 1 - smooth_sign(p, sign_eps) * p",
        MODEL_TESTS,
    ),
    _m(
        "model-damping-sign",
        "viscous damping with the wrong sign",
        '- p["g_damping"] * x["omega"]',
        '+ p["g_damping"] * x["omega"]',
        MODEL_TESTS,
    ),
    _m(
        "model-no-leakage",
        "internal leakage term dropped from the pressure equation",
        '-ctx.p["g_compress"] * ctx.x["omega"] - ctx.p["g_leak"] * ctx.x["p"]',
        '-ctx.p["g_compress"] * ctx.x["omega"]',
        MODEL_TESTS,
    ),
    _m(
        "model-compression-sign",
        "displacement flow with the wrong sign",
        '-ctx.p["g_compress"] * ctx.x["omega"] - ctx.p["g_leak"]',
        '+ctx.p["g_compress"] * ctx.x["omega"] - ctx.p["g_leak"]',
        MODEL_TESTS,
    ),
    # -- effects ---------------------------------------------------------------------------------
    _m(
        "effect-friction-sign",
        "Coulomb friction pushes along the motion",
        "rate = -level * smooth_sign(w, self._width(level, ctx.p))",
        "rate = level * smooth_sign(w, self._width(level, ctx.p))",
        EFFECT_TESTS,
    ),
    _m(
        "effect-deadzone-even",
        "dead zone output even in the input (both sides add)",
        "ctx.u = self._relu(c - d) - self._relu(-c - d)",
        "ctx.u = self._relu(c - d) + self._relu(-c - d)",
        EFFECT_TESTS,
    ),
    _m(
        "effect-backlash-contact-side",
        "backlash moving forward stops at the rear contact (the play passes through)",
        "ca.fmax(w, 0) * _contact((half - gap) / width)",
        "ca.fmax(w, 0) * _contact((half + gap) / width)",
        EDGE_TESTS,
    ),
    _m(
        "effect-corner-offset",
        "dead-zone and saturation corner shifted by its width (not exact beyond it)",
        "return r * r / (4 * w) + fmax(v - w, 0)",
        "return r * r / (4 * w) + fmax(v - 2 * w, 0)",
        EDGE_TESTS,
    ),
    _m(
        "effect-offset-sign",
        "sensor offset subtracted",
        'ctx.signals["y"] = ctx.signal("y", self.name) + ctx.p["y_offset"]',
        'ctx.signals["y"] = ctx.signal("y", self.name) - 2 * ctx.p["y_offset"]',
        EFFECT_TESTS,
    ),
    # -- initial state and cost ------------------------------------------------------------------
    _m(
        "problem-data-rule-sign",
        "the initial-state Newton step goes the wrong way",
        "J.T * (y0 - hu) / jj",
        "J.T * (hu - y0) / jj",
        PROBLEM_TESTS,
    ),
    _m(
        "problem-fit-x0-ignored",
        "fitted initial values not used on the estimation record",
        "X0[:, self.model.state_names.index(state)] = v[:, nm + k]",
        "X0[:, self.model.state_names.index(state)] = 0.0",
        PROBLEM_TESTS,
    ),
    # -- the loop --------------------------------------------------------------------------------
    _m(
        "loop-margin-inverted",
        "a candidate is accepted when it makes validation worse by less than the margin",
        "gain_ok = vr <= (1 - margin) * rmse_before",
        "gain_ok = vr <= (1 + margin) * rmse_before",
        LOOP_TESTS,
    ),
    _m(
        "loop-criterion-ignored",
        "the information criterion no longer has to agree",
        "crit_ok = crit_after < crit_before",
        "crit_ok = True",
        LOOP_TESTS,
    ),
    _m(
        "loop-no-noise-allowance",
        "gains within what noise allows are accepted",
        "beyond_ok = rmse_before ** 2 - vr ** 2 > allowance",
        "beyond_ok = True",
        LOOP_TESTS,
    ),
    _m(
        "loop-best-is-worst",
        "the loop accepts the worst of the passing candidates",
        'best = min(tried, key=lambda t: t[0].val.get("rmse", math.inf))',
        'best = max(tried, key=lambda t: t[0].val.get("rmse", math.inf))',
        LOOP_TESTS,
    ),
    # -- reliability: interrupts, widening, checks of values and units ---------------------------
    _m(
        "reliab-interrupt-forgotten",
        "a Ctrl-C swallowed by a solver is not raised again when the block ends",
        "        yield\n        check()\n",
        "        yield\n",
        RELIAB_TESTS,
    ),
    _m(
        "reliab-widen-wrong-side",
        "a box is widened on the side opposite to the edge the group ended at",
        "k = 0 if side == \"lower\" else 1",
        "k = 1 if side == \"lower\" else 0",
        ("tests/integration/test_widen.py",),
    ),
    _m(
        "reliab-fix-box-unchecked",
        "--fix values outside the box are accepted silently",
        "if not par.lower - slack <= v <= par.upper + slack:",
        "if False:",
        RELIAB_TESTS,
    ),
    _m(
        "reliab-rad-factor-inverted",
        "radians converted to degrees with the inverse factor",
        "\"rad\": 180.0 / math.pi",
        "\"rad\": math.pi / 180.0",
        RELIAB_TESTS,
    ),
    # -- discovery ---------------------------------------------------------------------------
    _m(
        "discover-odd-square-is-square",
        "the odd square q*|q| of the term library loses its sign",
        "return x * lib.fabs(x)",
        "return lib.fabs(x) * lib.fabs(x)",
        DISCOVER_TESTS,
    ),
    _m(
        "discover-hinge-knot-sign",
        "a hinge term bends at -c instead of c",
        "v = (x if family == \"hinge+\" else -x) - knot",
        "v = (x if family == \"hinge+\" else -x) + knot",
        DISCOVER_TESTS,
    ),
    _m(
        "discover-load-reaction-sign",
        "the load mode's reaction pushes the shaft along the load's acceleration",
        "ctx.add_rate(self.velocity, -k * f_c)",
        "ctx.add_rate(self.velocity, k * f_c)",
        (MODE_TESTS,),
    ),
    _m(
        "discover-load-relative-rate",
        "the load mode's relative velocity forgets the shaft's own reaction (1 + k -> 1)",
        "ctx.add_rate(f\"mode{i}_b\", rest - (1 + k) * f_c)",
        "ctx.add_rate(f\"mode{i}_b\", rest - f_c)",
        (MODE_TESTS,),
    ),
    _m(
        "discover-mode-mix-edge-ignored",
        "a mode whose mix (a load's ratio) ends at its box bound is still claimed",
        "for role, label in ((\"w\", \"frequency\"), (\"z\", \"damping\"),\n"
        "                        (\"k\", \"ratio\" if mode.velocity else \"mix\")):",
        "for role, label in ((\"w\", \"frequency\"), (\"z\", \"damping\")):",
        (MODE_TESTS,),
    ),
    _m(
        "discover-tie-by-selection",
        "of several acceptable discoveries the lowest selection error wins, even within noise",
        "step, fitted = min(tied, key=lambda t: t[1].crit)",
        "step, fitted = min(ok, key=lambda t: t[1].val_rmse)",
        (MODE_TESTS,),
    ),
    # -- several records: diagnosis and comparison --------------------------------------------
    _m(
        "multi-arx-rows-span-records",
        "ARX regression rows of several records built from their samples joined, so rows span "
        "two records",
        "rows = [regression_matrix(uk, yk, na, nb, nk) for uk, yk in zip(u, y, strict=True)]",
        "rows = [regression_matrix(np.concatenate(u), np.concatenate(y), na, nb, nk)]",
        (MULTI_TEST,),
    ),
    _m(
        "multi-evidence-unweighted",
        "the evidence of several records averaged instead of weighted by residual energy",
        "score = float(sum(e.score * en for e, en in zip(per, energy, strict=True)) / tot)",
        "score = float(np.mean([e.score for e in per]))",
        (MULTI_TEST,),
    ),
    _m(
        "multi-compare-first-record-only",
        "a comparison of several records reports the first record's scores as the pooled ones",
        "pooled[label] = pooled_score(list(part), ys)",
        "pooled[label] = per[0][label]",
        (MULTI_TEST,),
    ),
    _m(
        "multi-units-unchecked",
        "records of different signals or units accepted together",
        "a, b = getattr(first, attr), getattr(ds, attr)",
        "a = b = getattr(first, attr)",
        (MULTI_TEST,),
    ),
)


@dataclass
class Outcome:
    """Result of one mutation run."""

    id: str
    status: str  # killed, survived, timeout, error
    seconds: float
    file: str = ""
    detail: str = ""


def locate(snippet: str, root: Path = ROOT) -> tuple[Path | None, str]:
    """The file of ``root/hhra_phys`` holding ``snippet``, or ``None`` and the reason.

    The snippet must occur exactly once in the whole package, so a fragment copied to a second
    place makes the list fail loudly instead of mutating an arbitrary copy.
    """
    hits: list[tuple[Path, int]] = []
    for path in sorted((root / PACKAGE).rglob("*.py")):
        count = path.read_text(encoding="utf-8").count(snippet)
        if count:
            hits.append((path, count))
    total = sum(c for _, c in hits)
    if total == 0:
        return None, "snippet not found"
    if total > 1:
        where = ", ".join(f"{p.relative_to(root)} x{c}" for p, c in hits)
        return None, f"snippet occurs {total} times ({where})"
    return hits[0][0], ""


def _pytest(copy: Path, tests: tuple[str, ...], timeout: float) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests]
    return subprocess.run(
        cmd, cwd=copy, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )


def _last_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1][:160] if lines else ""


def run_one(mutation: Mutation, timeout: float) -> Outcome:
    """Copy the repository, apply ``mutation`` there and run its tests."""
    t0 = time.perf_counter()
    path, why = locate(mutation.snippet)
    if path is None:
        return Outcome(mutation.id, "error", 0.0, detail=why)
    rel = path.relative_to(ROOT)
    missing = [t for t in mutation.tests if not (ROOT / t).exists()]
    if missing:
        return Outcome(mutation.id, "error", 0.0, str(rel), f"missing tests {missing}")
    with tempfile.TemporaryDirectory(prefix="hhra-mut-") as tmp:
        copy = Path(tmp) / "repo"
        shutil.copytree(ROOT, copy, ignore=IGNORE)
        target = copy / rel
        text = target.read_text(encoding="utf-8")
        target.write_text(text.replace(mutation.snippet, mutation.replacement), encoding="utf-8")
        try:
            proc = _pytest(copy, mutation.tests, timeout)
        except subprocess.TimeoutExpired:
            return Outcome(mutation.id, "timeout", time.perf_counter() - t0, str(rel))
    # pytest: 0 all passed, 1 a test failed; anything else (collection or usage error) is
    # still a detected change, but say so
    status = "survived" if proc.returncode == 0 else "killed"
    detail = _last_line(proc.stdout)
    if proc.returncode not in (0, 1):
        detail = f"pytest exit {proc.returncode}: {detail}"
    return Outcome(mutation.id, status, time.perf_counter() - t0, str(rel), detail)


def baseline(tests: tuple[str, ...], timeout: float) -> str | None:
    """Run ``tests`` on an unmutated copy; an error message if they fail or import elsewhere."""
    with tempfile.TemporaryDirectory(prefix="hhra-mut-") as tmp:
        copy = Path(tmp) / "repo"
        shutil.copytree(ROOT, copy, ignore=IGNORE)
        env = dict(os.environ, PYTHONPATH=str(copy))
        probe = subprocess.run(
            [sys.executable, "-c", f"import {PACKAGE}; print({PACKAGE}.__file__)"],
            cwd=copy,
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
        # an installed copy shadowing the temporary one would make every mutation survive
        if not probe.stdout.strip().startswith(str(copy)):
            return f"{PACKAGE} is not imported from the copy: {probe.stdout.strip()}"
        try:
            proc = _pytest(copy, tests, timeout)
        except subprocess.TimeoutExpired:
            return f"the unmutated tests took longer than {timeout:g} s (raise --timeout)"
        if proc.returncode != 0:
            return f"unmutated tests fail: {_last_line(proc.stdout)}"
    return None


def print_table(outcomes: list[Outcome]) -> None:
    """A plain-text table and the surviving share."""
    width = max(len(o.id) for o in outcomes)
    print(f"{'mutation':<{width}}  {'status':<8}  {'s':>5}  file / detail")
    for o in outcomes:
        print(f"{o.id:<{width}}  {o.status:<8}  {o.seconds:5.1f}  {o.file}  {o.detail}")
    ran = [o for o in outcomes if o.status != "error"]
    survived = [o for o in ran if o.status == "survived"]
    errors = len(outcomes) - len(ran)
    share = len(survived) / len(ran) if ran else float("nan")
    print(
        f"\n{len(ran)} run, {len(ran) - len(survived)} killed (timeouts count as killed), "
        f"{len(survived)} survived: surviving share {share:.1%}; {errors} error(s)"
    )
    if survived:
        print("survivors: " + ", ".join(o.id for o in survived))


def main(argv: list[str] | None = None) -> int:
    """Command line entry point; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", metavar="ID", help="run only these mutations")
    parser.add_argument(
        "--group", nargs="+", metavar="G", help="run only these groups (optim, metrics, model)"
    )
    parser.add_argument("--list", action="store_true", help="list the mutations and exit")
    parser.add_argument("--json", metavar="OUT", help="write the outcomes to this JSON file")
    parser.add_argument(
        "--timeout", type=float, default=300.0, metavar="S", help="seconds per test run"
    )
    args = parser.parse_args(argv)

    ids = [m.id for m in MUTATIONS]
    if len(set(ids)) != len(ids):
        raise SystemExit("duplicate mutation ids in MUTATIONS")
    chosen = list(MUTATIONS)
    if args.only:
        unknown = sorted(set(args.only) - set(ids))
        if unknown:
            parser.error(f"unknown mutation id(s): {unknown}")
        chosen = [m for m in chosen if m.id in args.only]
    if args.group:
        chosen = [m for m in chosen if m.group in args.group]
    if args.list:
        for m in chosen:
            path, why = locate(m.snippet)
            where = str(path.relative_to(ROOT)) if path else f"ERROR: {why}"
            print(f"{m.id:<34} {where:<28} {m.description}")
        return 0
    if not chosen:
        parser.error("no mutation selected")

    tests = tuple(dict.fromkeys(t for m in chosen for t in m.tests))
    problem = baseline(tests, args.timeout)
    if problem:
        print(f"baseline failed, no mutation run: {problem}", file=sys.stderr)
        return 2
    outcomes = []
    for m in chosen:
        out = run_one(m, args.timeout)
        print(f"{out.status:<8} {out.id}", file=sys.stderr, flush=True)
        outcomes.append(out)
    print_table(outcomes)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        record = {
            "command": shlex.join(
                ["python", "benchmarks/mutations.py", *(sys.argv[1:] if argv is None else argv)]
            ),
            "outcomes": [
                asdict(o) | {"description": m.description}
                for o, m in zip(outcomes, chosen, strict=True)
            ],
        }
        Path(args.json).write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    if any(o.status == "error" for o in outcomes):
        return 2
    return 1 if any(o.status == "survived" for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
