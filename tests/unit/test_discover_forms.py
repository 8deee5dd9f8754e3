"""Discovery's forms of one entry's term led by different variables (``variable_forms``).

In steady motion a term in one variable can be first-order equivalent to a term in another
(a drag torque in the velocity and a pressure term): the screening then ranks them nearly
equal and the first pick alone must not decide the variable. Cases built by hand.
"""

from __future__ import annotations

import numpy as np

from hhra_phys.diagnosis.screening import Candidate, EntryScreen, _pursuit, variable_forms


def _screen(specs: list[str], S: np.ndarray, r: np.ndarray, k: int = 3) -> EntryScreen:
    picked, explained, beta = _pursuit(S, r, k)
    cands = [Candidate(s, np.zeros(len(r))) for s in specs]
    return EntryScreen("rate:omega", picked, explained, beta, cands, {}, S, r)


def _columns(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a, b, c = (rng.standard_normal(500) for _ in range(3))
    return a, b, c, rng.standard_normal(500)


def test_a_close_second_variable_leads_a_form_of_its_own():
    for seed in (1, 2, 3):
        a, b, c, e = _columns(seed)
        r = a + 0.1 * e
        # p's term fits r best, omega's nearly as well, theta's hardly at all
        S = np.column_stack([a + 0.05 * e, a + 0.3 * b, c, a * 0.2 + b])
        scr = _screen(["cube(p)", "odd2(omega)", "sin(theta)", "prod(p,omega)"], S, r)
        assert scr.candidates[scr.picked[0]].spec == "cube(p)"
        forms = variable_forms(scr, 3)
        leads = [f.candidates[f.picked[0]].spec for f in forms]
        assert leads == ["odd2(omega)"]  # theta explains too little; products lead none
        f = forms[0]
        assert f.picked[0] == 1 and len(f.picked) <= 3
        assert f.explained == sorted(f.explained) and 0 < f.explained[0] <= f.explained[-1]
        # the forced pursuit's coefficients fit its own picks
        beta, *_ = np.linalg.lstsq(S[:, f.picked], r, rcond=None)
        np.testing.assert_allclose(f.beta, beta)
        assert scr.picked[0] == 0  # the screen itself is left as it was


def test_no_forms_when_nothing_was_picked_or_no_other_variable_comes_close():
    a, b, c, e = _columns(4)
    r = a + 0.01 * e
    S = np.column_stack([a, c, b])
    scr = _screen(["lin(u)", "lin(p)", "cube(u)"], S, r)
    assert variable_forms(scr, 3) == []  # lin(p) explains far less than half of lin(u)'s
    assert variable_forms(scr, 3, fraction=0.0)[0].picked[0] == 1
    empty = EntryScreen("input", [], [], np.zeros(0), scr.candidates, {}, S, r)
    assert variable_forms(empty, 3) == []
