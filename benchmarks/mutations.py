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
    python benchmarks/mutations.py --list-set second --pytest-args='-m "not slow"'

Two lists: :data:`MUTATIONS` (written with the tests) and :data:`SECOND_HAND` (written from
the package code alone, without reading the tests first); ``--list-set`` picks
``first`` (default), ``second`` or ``all``, so each list's kill rate is reported on its own.
``--pytest-args`` appends arguments to every pytest run (e.g. ``-m "not slow"`` for the
suite ``.ci/run`` runs by default).

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
#: Issue 35's three areas: members' own initial states, the backward step's choice, the
#: widening's release rule (unit tests of seconds; the fits of test_widen.py are not needed).
X0_TESTS = ("tests/unit/test_vectorize.py",)
BACKWARD_TESTS = ("tests/unit/test_loop_backward.py",)
WIDEN_RULE_TESTS = ("tests/unit/test_widen_rule.py",)
SETTLE_TESTS = ("tests/unit/test_loop_settle.py",)


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
        'rate = -level * (ca.tanh(w / width) if self.profile == "tanh"',
        'rate = level * (ca.tanh(w / width) if self.profile == "tanh"',
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
        "clear = vr <= (1 - margin) * rmse_before",
        "clear = vr <= (1 + margin) * rmse_before",
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
        "beyond = rmse_before ** 2 - vr ** 2 > allowance",
        "beyond = True",
        LOOP_TESTS,
    ),
    _m(
        "loop-best-is-worst",
        "the loop accepts the worst of the passing candidates",
        "best = min(sel(s) for s, _ in candidates)",
        "best = max(sel(s) for s, _ in candidates)",
        ("tests/unit/test_selection.py", *LOOP_TESTS),
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
        "return (lo / 10, hi) if side == \"lower\" else (lo, hi * 10)",
        "return (lo, hi * 10) if side == \"lower\" else (lo / 10, hi)",
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
        'v = (q[0] if family == "hinge+" else -q[0]) - knot',
        'v = (q[0] if family == "hinge+" else -q[0]) + knot',
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
        "of several acceptable candidates the lowest selection error wins, even within noise",
        "step, payload = min(sensors, key=lambda c: (c[0].criterion, sel(c[0])))",
        "step, payload = min(candidates, key=lambda c: sel(c[0]))",
        ("tests/unit/test_selection.py", MODE_TESTS),
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
    # -- issue 35: three rules mutations written outside the project got past -----------------
    # Members starting from different states (per-member initial states across lanes). The old
    # tests gave every member the same start, so any permutation of the starts passed.
    _m(
        "simd-x0-rows-reshaped",
        "per-member initial states (n_pop, nx) laid out by a reshape instead of a transpose",
        "X0 = x0a.T.copy()",
        "X0 = x0a.reshape(nx, n_pop)",
        X0_TESTS,
    ),
    _m(
        "simd-x0-groups-lanes-swapped",
        "vector code: member g*width + l's start packed as member l*groups + g",
        "X.reshape(X.shape[0], groups, width).transpose(1, 0, 2).reshape(-1, width)",
        "X.reshape(X.shape[0], width, groups).transpose(2, 0, 1).reshape(-1, width)",
        X0_TESTS,
    ),
    _m(
        "simd-x0-lanes-reversed",
        "interleaved scalar lanes read their states in reverse lane order",
        "xk, pk = x[:, lane], p[:, lane]",
        "xk, pk = x[:, lanes - 1 - lane], p[:, lane]",
        X0_TESTS,
    ),
    # Which accepted effect the backward step takes out: the removable one whose removal
    # leaves the lowest selection RMSE, every effect before the newest checked.
    _m(
        "loop-backward-drops-largest",
        "of the removable effects the backward step takes out the one leaving the highest RMSE",
        "_, step, p2, r2, free_r = min(out, key=lambda t: t[0])",
        "_, step, p2, r2, free_r = max(out, key=lambda t: t[0])",
        BACKWARD_TESTS,
    ),
    _m(
        "loop-backward-drops-first",
        "the backward step takes out the first removable effect (in the order accepted)",
        "_, step, p2, r2, free_r = min(out, key=lambda t: t[0])",
        "_, step, p2, r2, free_r = out[0]",
        BACKWARD_TESTS,
    ),
    _m(
        "loop-backward-drops-last",
        "the backward step takes out the last removable effect checked",
        "_, step, p2, r2, free_r = min(out, key=lambda t: t[0])",
        "_, step, p2, r2, free_r = out[-1]",
        BACKWARD_TESTS,
    ),
    _m(
        "loop-backward-drops-lowest-criterion",
        "the backward step takes out the removable effect with the lowest criterion, not RMSE",
        "_, step, p2, r2, free_r = min(out, key=lambda t: t[0])",
        "_, step, p2, r2, free_r = min(out, key=lambda t: t[1].criterion_before)",
        BACKWARD_TESTS,
    ),
    _m(
        "loop-backward-checks-newest",
        "the backward step checks the newest effect and skips the oldest",
        "    for effect in chosen[:-1]:",
        "    for effect in chosen[1:]:",
        BACKWARD_TESTS,
    ),
    # The rule that lets a group out of its default box.
    _m(
        "widen-need-strict",
        "a side is widened only when the predicted gain exceeds need (not reaches it)",
        "new = widened_box(par, side) if predicted >= need else None",
        "new = widened_box(par, side) if predicted > need else None",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-excess-limit-strict",
        "a residual exactly at the excess limit counts as model error",
        "need = WIDEN_MIN_GAIN if excess <= WIDEN_MAX_EXCESS else WIDEN_CLEAR_GAIN",
        "need = WIDEN_MIN_GAIN if excess < WIDEN_MAX_EXCESS else WIDEN_CLEAR_GAIN",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-need-swapped",
        "the clear gain asked while the residual is mostly noise, the small one otherwise",
        "need = WIDEN_MIN_GAIN if excess <= WIDEN_MAX_EXCESS else WIDEN_CLEAR_GAIN",
        "need = WIDEN_CLEAR_GAIN if excess <= WIDEN_MAX_EXCESS else WIDEN_MIN_GAIN",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-release-inward-counts",
        "a release whose step moves the group back inside its box still counts as a gain",
        "gains.append((base - ssr) / total if outward and total > 0 else 0.0)",
        "gains.append((base - ssr) / total if total > 0 else 0.0)",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-release-alone",
        "the released group moves alone: the other free groups do not follow it",
        "cols = [j for j in range(problem.n_free) if j not in held or j == i]",
        "cols = [i]",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-limit-one-more-decade",
        "a side may be widened once more at MAX_WIDEN_DECADES beyond the default box",
        "return bool(abs(np.log10(edge / first)) < MAX_WIDEN_DECADES - 0.5)",
        "return bool(abs(np.log10(edge / first)) <= MAX_WIDEN_DECADES)",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-limit-lower-unbounded",
        "the decade limit without abs(): a lower side is widened without end",
        "return bool(abs(np.log10(edge / first)) < MAX_WIDEN_DECADES - 0.5)",
        "return bool(np.log10(edge / first) < MAX_WIDEN_DECADES - 0.5)",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-no-stop",
        "rounds go on after a refit that gained less than WIDEN_MIN_GAIN",
        "        if gain < WIDEN_MIN_GAIN or not confirmed:\n            break",
        "        if gain < 0 or not confirmed:\n            break",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-search-unchecked",
        "a widening round searches the wider box whatever the refiners' check gained",
        "    if more and not (cost > 0 and (cost - loc_cost) / cost >= need):",
        "    if False:",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-local-ignored",
        "a confirmed round keeps the global search's optimum even where the local one is better",
        "    if loc_cost < new_cost:\n        return z_loc, loc_cost, True",
        "    if False:\n        return z_loc, loc_cost, True",
        WIDEN_RULE_TESTS,
    ),
    _m(
        "loop-settle-library-spares-only-library",
        "a library effect at the noise level no longer spares discovery",
        '_SETTLES = {"effect": ("effect", "discovered", "mode"), "sensor": ("sensor",),',
        '_SETTLES = {"effect": ("effect",), "sensor": ("sensor",),',
        SETTLE_TESTS,
    ),
    _m(
        "loop-widen-any-candidate",
        "every candidate ending at a box edge is widened, contender or not",
        '    if float(r2.metrics["est"]["mse"]) > worth:',
        "    if False:",
        SETTLE_TESTS,
    ),
    _m(
        "loop-settle-sensor-spared",
        "a library effect at the noise level spares the sensor effects too",
        '_SETTLES = {"effect": ("effect", "discovered", "mode"), "sensor": ("sensor",),',
        '_SETTLES = {"effect": ("effect", "sensor", "discovered", "mode"), "sensor": ("sensor",),',
        SETTLE_TESTS,
    ),
    _m(
        "widen-signed-zero-side",
        "a signed lower side at zero is moved (to zero again: the sign check read as <= 0)",
        'if side == "lower" and lo < 0:',
        'if side == "lower" and lo <= 0:',
        WIDEN_RULE_TESTS,
    ),
    _m(
        "widen-user-box",
        "a box the user gave (not a default one) is widened like a default one",
        "if name not in origin or name in box or not _may_widen(par, side, origin[name]):",
        "if name in box or not _may_widen(par, side, origin.get(name, (par.lower, par.upper))):",
        WIDEN_RULE_TESTS,
    ),
)


# --- the second hand's list ------------------------------------------------------------------
# Written from the package code alone, without reading the tests or the list above, so that
# its kill rate measures the tests against bugs their authors did not list (issue 23). The
# test files named for each were picked by their names only. Kept apart from MUTATIONS so the
# two kill rates are reported separately (``--list-set second``); docs/testing.md has both.

# The oracle files (tests/unit/test_oracles_*.py, written after the first run for its
# survivors) come first in each tuple, so -x stops at them; docs/testing.md has the first
# run's figures with the tests named before them.
CYL_TESTS = ("tests/unit/test_oracles_cylinder.py", "tests/integration/test_cylinder.py")
SIMD_TESTS = ("tests/unit/test_simulate.py", "tests/unit/test_vectorize.py")
RULE_TESTS = ("tests/unit/test_oracles_loop.py", "tests/unit/test_loop_rule.py",
              "tests/unit/test_loop_backward.py")
DISC_TESTS = ("tests/unit/test_oracles_discover.py", "tests/unit/test_oracles_modes.py",
              "tests/integration/test_discover.py")
MULTI_TESTS = ("tests/unit/test_oracles_multi.py", "tests/integration/test_multi.py",
               "tests/integration/test_multi_diagnose.py")
DESIGN_TESTS = ("tests/unit/test_oracles_design.py", "tests/integration/test_design.py")
TIME_TESTS = ("tests/unit/test_oracles_time.py", "tests/unit/test_units.py",
              "tests/unit/test_data.py", "tests/unit/test_data_loaders.py",
              "tests/unit/test_cli_args.py")
ARX_TESTS = ("tests/unit/test_oracles_arx.py", "tests/unit/test_arx.py")
CONTROL_TESTS = ("tests/unit/test_oracles_control.py", "tests/unit/test_control.py")
WIDEN_TESTS = ("tests/integration/test_widen.py",)
VALVE_TESTS = ("tests/unit/test_model.py", "tests/unit/test_effects.py")
#: The reference rig's right-hand-side comparison per effect (first run: not named, 2 survived).
EFFECTS2_TESTS = ("tests/unit/test_effects.py", "tests/unit/test_effect_signatures.py",
                  "tests/integration/test_reference_rig.py")
METRICS2_TESTS = ("tests/unit/test_metrics.py", "tests/unit/test_metrics_hand.py")
OPTIM2_TESTS = ("tests/unit/test_optim.py", "tests/unit/test_optim_steps.py")

SECOND_HAND: tuple[Mutation, ...] = (
    # -- the cylinder model: chamber volumes and groups ---------------------------------------
    _m("cyl-one-dead-volume", "total oil volume counts the lines' dead volume once, not per side",
       "return self.A_p * self.stroke + 2.0 * self.V_dead",
       "return self.A_p * self.stroke + self.V_dead", CYL_TESTS),
    _m("cyl-compliance-half", "hydraulic capacitance V_t/(2 beta_e) (one chamber's volume rule)",
       "return self.V_t / (4.0 * self.beta_e)", "return self.V_t / (2.0 * self.beta_e)",
       CYL_TESTS),
    _m("cyl-beta-from-groups", "bulk modulus solved from c_compress with 2 A_p instead of 4 A_p",
       'beta_e = g["c_compress"] * self.V_t * self.p_s / (4.0 * self.A_p)',
       'beta_e = g["c_compress"] * self.V_t * self.p_s / (2.0 * self.A_p)', CYL_TESTS),
    _m("cyl-area-no-rod", "annulus area forgets the rod: pi/4 bore^2",
       "return 0.25 * math.pi * (self.bore**2 - self.rod**2)",
       "return 0.25 * math.pi * self.bore**2", CYL_TESTS),
    _m("cyl-tf-no-damping-leak", "transfer function's s coefficient forgets c_damping*L",
       'lambda g: g["c_spring"] + g["c_damping"] * leak(g)\n',
       'lambda g: g["c_spring"] + 0.0 * leak(g)\n', CYL_TESTS),
    # -- SIMD packing of initial states and parameters ----------------------------------------
    _m("simd-pack-x0-untransposed", "vector layout of the initial states without the transpose",
       "X.reshape(X.shape[0], groups, width).transpose(1, 0, 2).reshape(-1, width)",
       "X.reshape(groups, X.shape[0], width).reshape(-1, width)", SIMD_TESTS),
    _m("simd-pack-params-untransposed", "vector layout of the parameters without the transpose",
       "P.reshape(groups, width, -1).transpose(0, 2, 1).reshape(-1, width)",
       "P.reshape(groups, -1, width).reshape(-1, width)", SIMD_TESTS),
    _m("simd-cost-unpack", "vector cost's final augmented states read back without the transpose",
       "xa = xa.reshape(groups, nx + 2, width).transpose(1, 0, 2).reshape(nx + 2, -1)",
       "xa = xa.reshape(nx + 2, groups, width).reshape(nx + 2, -1)", SIMD_TESTS),
    _m("simd-output-lanes", "vector outputs read back as (groups, width, chunk)",
       "outs[0]).reshape(groups, self.chunk, width)[:, :m].transpose(0, 2, 1)",
       "outs[0]).reshape(groups, width, self.chunk)[:, :, :m]", SIMD_TESTS),
    _m("simd-fmin-is-fmax", "lane-wise fmin selects the larger value",
       "return hv_select(b.v != b.v, a, hv_select(a.v <= b.v, a, b));",
       "return hv_select(b.v != b.v, a, hv_select(a.v >= b.v, a, b));", SIMD_TESTS),
    _m("simd-lanes-unpack-order", "interleaved lanes unpacked with block and sample axes swapped",
       "arr.transpose(3, 0, 2, 1).reshape(n_members, nb * self.block)",
       "arr.transpose(3, 0, 1, 2).reshape(n_members, nb * self.block)", SIMD_TESTS),
    # -- the loop: information criterion, noise allowance, backward step ----------------------
    _m("loop-bic-log10", "BIC penalty k*log10(N) instead of k*ln(N)",
       'pen = k * math.log(n) if kind == "bic" else 2.0 * k',
       'pen = k * math.log10(n) if kind == "bic" else 2.0 * k', RULE_TESTS),
    _m("loop-ic-no-n", "information criterion ln(RSS/N) + pen, the N factor forgotten",
       "return n * math.log(mse) + pen", "return math.log(mse) + pen", RULE_TESTS),
    _m("loop-ic-k-without-x0", "k does not count the fitted initial state",
       "k = len(result.free)\n",
       'k = len([f for f in result.free if not f.startswith("x0_")])\n', RULE_TESTS),
    _m("loop-allowance-no-minus-one", "noise allowance (1+tol)^2 noise^2, the -1 forgotten",
       "return ((1 + noise_tol) ** 2 - 1) * noise ** 2 if",
       "return (1 + noise_tol) ** 2 * noise ** 2 if", RULE_TESTS),
    _m("loop-allowance-noise-unsquared", "noise allowance ((1+tol)^2-1)*noise (not noise^2)",
       "return ((1 + noise_tol) ** 2 - 1) * noise ** 2 if",
       "return ((1 + noise_tol) ** 2 - 1) * noise if", RULE_TESTS),
    _m("loop-gain-margin-sign", "clear gain read as rmse_after <= (1 + margin) * rmse_before",
       "clear = vr <= (1 - margin) * rmse_before",
       "clear = vr <= (1 + margin) * rmse_before", RULE_TESTS),
    _m("loop-beyond-diff-squared", "variance removed computed as (rmse_before - rmse_after)^2",
       "beyond = rmse_before ** 2 - vr ** 2 > allowance",
       "beyond = (rmse_before - vr) ** 2 > allowance", RULE_TESTS),
    _m("loop-backward-swapped", "backward step calls the rule with the two models swapped",
       "keep, reason = acceptance(rmse_without, rmse_with, crit_without, crit_with, margin,",
       "keep, reason = acceptance(rmse_with, rmse_without, crit_with, crit_without, margin,",
       RULE_TESTS),
    _m("loop-backward-from-three", "backward step only once three effects are accepted",
       "if o.backward and len(self.chosen) >= 2 and not self._over_budget():",
       "if o.backward and len(self.chosen) > 2 and not self._over_budget():",
       RULE_TESTS + ("tests/integration/test_diagnose.py",)),
    _m("loop-at-noise-and", "at the noise level only when small AND white (not or)",
       'if level["white"]:\n        return True\n    return bool(level["ratio"] <=',
       'if not level["white"]:\n        return False\n    return bool(level["ratio"] <=',
       RULE_TESTS),
    # -- per-record parameters and the pooled noise of several records ------------------------
    _m("multi-pooled-noise-unsquared", "records' noise pooled from sigma, not sigma^2",
       "sigma = float(np.sqrt(sum(rk.size * s ** 2 for rk, s in zip(rs, sigmas, strict=True))",
       "sigma = float(np.sqrt(sum(rk.size * s for rk, s in zip(rs, sigmas, strict=True))",
       RULE_TESTS + MULTI_TESTS),
    _m("multi-ljung-box-dof", "pooled Ljung-Box degrees of freedom: the largest, not the sum",
       'sum(w["lags"] for w in tests)))', 'max(w["lags"] for w in tests)))',
       RULE_TESTS + MULTI_TESTS),
    _m("multi-per-record-shared", "per-record parameters are stacked as one shared value",
       'specific = several and (par.name in own or par.name.startswith("x0_"))',
       'specific = several and par.name.startswith("x0_")', MULTI_TESTS),
    _m("multi-record-values-first", "every record reports the first record's own values",
       '"values": {n: float(pr.full(vk)[model.params.index(n)])',
       '"values": {n: float(problem.full(v)[model.params.index(n)])', MULTI_TESTS),
    # -- discovery: printed coefficients and the load-mode rule -------------------------------
    _m("disc-print-lin-scale", "printed linear coefficient multiplied by the scale, not divided",
       '"lin": (a / s[0], f"{args[0]}")', '"lin": (a * s[0], f"{args[0]}")', DISC_TESTS),
    _m("disc-print-sq-scale", "printed square coefficient divided by s, not s^2",
       '"sq": (a / s[0] ** 2, f"{args[0]}^2")', '"sq": (a / s[0], f"{args[0]}^2")', DISC_TESTS),
    _m("disc-print-sat-width", "printed tanh width s*2 instead of s/2",
       'f"tanh({args[0]}/{g.format(s[0] / 2)})"', 'f"tanh({args[0]}/{g.format(s[0] * 2)})"',
       DISC_TESTS),
    _m("disc-print-prod-scale", "printed product coefficient divided by one scale only",
       '((a / (s[0] * s[1]), f"{args[0]}*{args[1]}")', '((a / s[0], f"{args[0]}*{args[1]}")',
       DISC_TESTS),
    _m("disc-load-mode-count", "load mode claimed with as many resonances as without it",
       "if len(both) <= len(own):", "if len(both) < len(own):",
       DISC_TESTS + ("tests/integration/test_discover_mode.py",)),
    _m("disc-separation-one-sided", "mode separation checked only above the own resonance",
       "if max(w / w_own, w_own / w) < MODE_SEPARATION:", "if w / w_own < MODE_SEPARATION:",
       DISC_TESTS + ("tests/integration/test_discover_mode.py",)),
    # -- design: Fisher information, marginalisation, input limit -----------------------------
    _m("design-fisher-sigma", "Fisher information J^T J / sigma (not sigma^2)",
       "info = J.T @ J / self.sigma**2", "info = J.T @ J / self.sigma", DESIGN_TESTS),
    _m("design-conditional", "initial angle conditioned on (inverse of the parameter block) "
       "instead of marginalised",
       "cov = np.linalg.inv(info)", "cov = np.linalg.inv(info[:len(self.free), :len(self.free)])",
       DESIGN_TESTS),
    _m("design-max-input-signed", "default input limit max(u), not max|u|",
       "max_input = float(np.max(np.abs(reference_input)))",
       "max_input = float(np.max(reference_input))", DESIGN_TESTS),
    _m("design-e-smallest", "E-criterion takes the smallest eigenvalue",
       "return float(w[-1]) if w[0] > 0 else math.inf",
       "return float(w[0]) if w[0] > 0 else math.inf", DESIGN_TESTS),
    _m("design-widths-variance", "predicted widths from the variance, the square root forgotten",
       "sd[:m] = np.sqrt(np.clip(np.diag(cov), 0, None))",
       "sd[:m] = np.clip(np.diag(cov), 0, None)", DESIGN_TESTS),
    _m("design-draws-variance", "covariance draws scaled by eigenvalues, not their roots",
       "L = V * np.sqrt(np.clip(w, 0, None))", "L = V * np.clip(w, 0, None)", DESIGN_TESTS),
    # -- time-unit conversion -----------------------------------------------------------------
    _m("time-us-factor", "--time-unit us divides by 1000, like ms",
       'TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6}',
       'TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-3}', TIME_TESTS),
    _m("time-mrad-factor", "mrad to deg factor 1.8/pi (ten times too large)",
       '"mrad": 0.18 / math.pi', '"mrad": 1.8 / math.pi', TIME_TESTS),
    _m("time-dt-over-n", "sample period (t[-1]-t[0])/N instead of /(N-1)",
       "return float((self.t[-1] - self.t[0]) / (self.n - 1))",
       "return float((self.t[-1] - self.t[0]) / self.n)", TIME_TESTS),
    _m("time-axis-from-one", "time axis built from fs starts at dt, not 0",
       "return np.arange(n, dtype=np.float64) / float(fs), False",
       "return np.arange(1, n + 1, dtype=np.float64) / float(fs), False", TIME_TESTS),
    # -- ARX path: continuous poles, FFRLS ----------------------------------------------------
    _m("arx-cpoles-factor", "continuous poles s = (1/T)(z-1)/(z+1): the factor 2 forgotten",
       "return 2.0 / dt * (z - 1.0) / (z + 1.0)", "return 1.0 / dt * (z - 1.0) / (z + 1.0)",
       ARX_TESTS),
    _m("arx-ffrls-gain-no-xi", "FFRLS gain P phi / (1 + phi^T P phi): xi forgotten",
       "gain = pf / (xi[k] + f @ pf)", "gain = pf / (1.0 + f @ pf)", ARX_TESTS),
    _m("arx-ffrls-cov-times-xi", "FFRLS covariance multiplied by xi instead of divided",
       "cov = (cov - np.outer(gain, pf)) / xi[k]", "cov = (cov - np.outer(gain, pf)) * xi[k]",
       ARX_TESTS),
    _m("arx-forget-offset", "forgetting factor's first update uses xi(1), not xi(0)",
       "return 1.0 - (1.0 - xi_init) * xi0 ** np.arange(n)",
       "return 1.0 - (1.0 - xi_init) * xi0 ** np.arange(1, n + 1)", ARX_TESTS),
    _m("arx-tustin-inverse-b", "inverse Tustin b = abc[1] T^2/2 (not /4)",
       '"b": float(abc[1] * dt**2 / 4.0 / a)', '"b": float(abc[1] * dt**2 / 2.0 / a)',
       ARX_TESTS),
    # -- control export: operating point, closed-loop figures ---------------------------------
    _m("ctl-op-velocity-rad", "operating point's velocity [deg/s] used as rad/s",
       '"omega": math.radians(float(named.get("velocity", 0.0))),',
       '"omega": float(named.get("velocity", 0.0)),', CONTROL_TESTS),
    _m("ctl-rms-is-std", "tracking RMS computed as the standard deviation (mean removed)",
       'return {"rms": float(np.sqrt(np.mean(e**2))),', 'return {"rms": float(np.std(e)),',
       CONTROL_TESTS),
    _m("ctl-settle-offbyone", "settling time is the last sample outside the band",
       "settle = float(t[outside[-1] + 1])", "settle = float(t[outside[-1]])", CONTROL_TESTS),
    _m("ctl-sse-sign", "steady-state error y - r instead of r - y",
       '"steady_state_error": float(np.mean(self.r[-k:] - self.y[-k:])),',
       '"steady_state_error": float(np.mean(self.y[-k:] - self.r[-k:])),', CONTROL_TESTS),
    _m("ctl-inverse-tustin-dt", "ARX inverse Tustin with sT instead of sT/2",
       "plus, minus = np.array([dt / 2, 1.0]), np.array([-dt / 2, 1.0])",
       "plus, minus = np.array([dt, 1.0]), np.array([-dt, 1.0])", CONTROL_TESTS),
    # -- the box widening's release rule ------------------------------------------------------
    _m("widen-outward-sign", "release rule reads 'outward' with the sides swapped",
       'outward = dz[cols.index(i)] * (1.0 if side == "upper" else -1.0) > 0',
       'outward = dz[cols.index(i)] * (1.0 if side == "lower" else -1.0) > 0', WIDEN_TESTS),
    _m("widen-excess-no-n", "excess over noise compares sigma^2 (not N sigma^2) with the SSR",
       "max(0.0, 1.0 - r.size * noise_level(r, inputs) ** 2 / total)",
       "max(0.0, 1.0 - noise_level(r, inputs) ** 2 / total)", WIDEN_TESTS),
    # -- valve law, effects -------------------------------------------------------------------
    _m("valve-drop-sign", "orifice pressure drop 1 + sign(I) p",
       "drop = 1 - smooth_sign(cmd, sign_eps) * p", "drop = 1 + smooth_sign(cmd, sign_eps) * p",
       VALVE_TESTS),
    _m("valve-sqrt-normaliser", "signed-root normaliser forgets -sqrt(delta) (0.1 % gain error)",
       "norm = 1.0 / (math.sqrt(1.0 + delta) - math.sqrt(delta))",
       "norm = 1.0 / math.sqrt(1.0 + delta)", VALVE_TESTS),
    _m("eff-backlash-full-play", "backlash contact at the whole play, not half of it",
       'half = 0.5 * ctx.p["play"] / RAD2DEG', 'half = ctx.p["play"] / RAD2DEG', EFFECTS2_TESTS),
    _m("eff-gravity-swapped", "gravity load's cos and sin groups swapped",
       '-(ctx.p["g_grav_cos"] * ca.cos(th)\n'
       '                                                + ctx.p["g_grav_sin"] * ca.sin(th)))',
       '-(ctx.p["g_grav_cos"] * ca.sin(th)\n'
       '                                                + ctx.p["g_grav_sin"] * ca.cos(th)))',
       EFFECTS2_TESTS),
    _m("eff-stribeck-exp-abs", "Stribeck curve exp(-|w/v|) instead of exp(-(w/v)^2)",
       'ca.exp(-(w / ctx.p["v_stribeck"]) ** 2)', 'ca.exp(-ca.fabs(w / ctx.p["v_stribeck"]))',
       EFFECTS2_TESTS),
    _m("eff-deadzone-even", "dead zone's negative branch added instead of subtracted",
       "ctx.u = self._relu(c - d) - self._relu(-c - d)",
       "ctx.u = self._relu(c - d) + self._relu(-c - d)", EFFECTS2_TESTS),
    # -- metrics ------------------------------------------------------------------------------
    _m("met-vaf-mse", "VAF from the mean squared error, not the error's variance",
       "value = (1.0 - np.var(yy - yh, axis=-1) / var_y) * 100.0",
       "value = (1.0 - np.mean((yy - yh) ** 2, axis=-1) / var_y) * 100.0", METRICS2_TESTS),
    _m("met-itae-step-n", "ITAE's time step (t[-1]-t[0])/N",
       "step = (tt[-1] - tt[0]) / (n - 1) if n > 1 else 0.0",
       "step = (tt[-1] - tt[0]) / n if n > 1 else 0.0", METRICS2_TESTS),
    _m("met-fit-scale-n-1", "FIT's norm of y - mean(y) from var * (N-1)",
       'scale = np.sqrt(_spread(yy, "FIT") * yy.size)',
       'scale = np.sqrt(_spread(yy, "FIT") * (yy.size - 1))', METRICS2_TESTS),
    # -- optimisers ---------------------------------------------------------------------------
    _m("opt-gwo-a-to-one", "GWO's a falls from 2 to 1 only",
       "return 2.0 - 2.0 * t / max(horizon, 1)", "return 2.0 - t / max(horizon, 1)",
       OPTIM2_TESTS),
    _m("opt-de-cr-half", "DE crossover rate 0.5*rand instead of 0.5*(1+rand)",
       "rate = 0.5 * (1.0 + u[:, d : d + 1]) if cr is None else cr",
       "rate = 0.5 * u[:, d : d + 1] if cr is None else cr", OPTIM2_TESTS),
    _m("opt-pso-social-pbest", "PSO's social term pulls toward the personal best",
       "+ self.c2 * r[1] * (self.x_best - x)", "+ self.c2 * r[1] * (self.pbest - x)",
       OPTIM2_TESTS),
    _m("opt-hgwo-beta-leader", "H-GWO mutation around the beta wolf, not the alpha",
       "mutant = self.lam * self.leaders[0] + self.F * (x[r[:, 0]] - x[r[:, 1]])",
       "mutant = self.lam * self.leaders[1] + self.F * (x[r[:, 0]] - x[r[:, 1]])",
       OPTIM2_TESTS),
    _m("opt-box-uniform-upper", "initial population spread by the upper bound, not the width",
       "return self.lower + rng.random((n, self.dim)) * self.width",
       "return self.lower + rng.random((n, self.dim)) * self.upper", OPTIM2_TESTS),
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


#: Extra pytest arguments of every run (``--pytest-args``).
PYTEST_EXTRA: list[str] = []


def _pytest(copy: Path, tests: tuple[str, ...], timeout: float) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *PYTEST_EXTRA,
           *tests]
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
    parser.add_argument(
        "--list-set", choices=("first", "second", "all"), default="first",
        help="which list: first (MUTATIONS, default), second (SECOND_HAND) or all",
    )
    parser.add_argument(
        "--pytest-args", default="", metavar="ARGS",
        help='arguments appended to every pytest run, e.g. \'-m "not slow"\'',
    )
    args = parser.parse_args(argv)
    PYTEST_EXTRA[:] = shlex.split(args.pytest_args)

    every = [*MUTATIONS, *SECOND_HAND]
    ids = [m.id for m in every]
    if len(set(ids)) != len(ids):
        raise SystemExit("duplicate mutation ids in MUTATIONS and SECOND_HAND")
    chosen = {"first": list(MUTATIONS), "second": list(SECOND_HAND), "all": every}[args.list_set]
    ids = [m.id for m in chosen]
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
