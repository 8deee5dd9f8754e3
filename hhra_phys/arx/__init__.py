"""The paper's black-box path: Tustin discretisation, ARX models and their estimators.

Structure (the paper's eq. 11/13, general orders)::

    y(k) = -a_1 y(k-1) - ... - a_na y(k-na) + b_1 u(k-nk) + ... + b_nb u(k-nk-nb+1)

i.e. ``A(q^-1) y(k) = q^-nk B(q^-1) u(k)`` with ``A = 1 + a_1 q^-1 + ...`` and
``B = b_1 + b_2 q^-1 + ...``. The coefficient vector is ``theta = [a_1..a_na, b_1..b_nb]`` and
the regressor ``phi(k) = [-y(k-1) .. -y(k-na), u(k-nk) .. u(k-nk-nb+1)]``. The paper's model
(eq. 13) is ``na = nb = 3, nk = 1``. Units follow the data: ``y`` in the output unit (deg for the
rig), ``u`` in the input unit (mA), ``a_i`` dimensionless, ``b_i`` [output unit / input unit].

Contents

* :func:`tustin_coefficients` / :func:`tustin_inverse`: the Tustin image of the paper's
  ``G(s) = k_v / (a s^3 + b s^2 + c s)`` with the corrected algebra of eq. 12, and back.
* :class:`ARXModel`: free-run :meth:`~ARXModel.simulate` (from the input only),
  one-step :meth:`~ARXModel.predict`, :meth:`~ARXModel.to_control`.
* :func:`regression_matrix`; estimators :func:`fit_ls`, :func:`fit_rls`, :func:`fit_ffrls`;
  :func:`fit_metaheuristic` (PSO, GWO, H-GWO minimising the ITAE of the free-run output,
  vectorised over the population with :func:`simulate_population`) and the paper's hybrid
  :func:`fit_ffrls_hgwo` with the search box of eq. 29 (:func:`hybrid_box`).

Initial conditions. :meth:`ARXModel.simulate` and :meth:`ARXModel.predict` take the samples
before the first one as ``y_init`` and ``u_init`` (chronological, the last value is ``y(-1)``);
without them the past is zero (the LTI zero state, which is what python-control's
``forced_response`` uses). The fitting functions that simulate (:func:`fit_metaheuristic`,
:func:`fit_ffrls_hgwo`) instead assume by default that the record *starts at rest at its first
measured output*: past outputs equal ``y[0]``, past inputs zero. The regression-based
estimators never invent a past: without ``y_init``/``u_init`` the first
``max(na, nk + nb - 1)`` samples serve only as history.

Modules: :mod:`.structure` (the ARX model, its free run, prediction and regressors),
:mod:`.tustin` (the continuous model's Tustin image and its inverse), :mod:`.estimators`
(LS, RLS, FFRLS and the :class:`ARXFit` result) and :mod:`.search` (the metaheuristics on the
ITAE and the paper's FFRLS + H-GWO hybrid). Import from ``hhra_phys.arx``: every name stays
here.
"""

from __future__ import annotations

from hhra_phys.arx.estimators import (
    FFRLS_XI0,
    FFRLS_XI_INIT,
    RLS_P0,
    RLS_THETA0,
    ARXFit,
    ConditioningWarning,
    fit_ffrls,
    fit_ls,
    fit_rls,
    forgetting_factor,
    recursive_least_squares,
)
from hhra_phys.arx.search import (
    DEFAULT_ZETA_S,
    METAHEURISTIC_OPTIONS,
    PAPER_BOX,
    HybridOptions,
    MetaheuristicOptions,
    fit_ffrls_hgwo,
    fit_metaheuristic,
    hybrid_box,
    itae_cost,
)
from hhra_phys.arx.structure import (
    MAX_POLE_RADIUS,
    ARXModel,
    pole_radius,
    regression_matrix,
    simulate_population,
)
from hhra_phys.arx.tustin import tustin_arx, tustin_coefficients, tustin_inverse

__all__ = [
    "DEFAULT_ZETA_S",
    "FFRLS_XI0",
    "FFRLS_XI_INIT",
    "MAX_POLE_RADIUS",
    "METAHEURISTIC_OPTIONS",
    "PAPER_BOX",
    "RLS_P0",
    "RLS_THETA0",
    "ARXFit",
    "ARXModel",
    "ConditioningWarning",
    "HybridOptions",
    "MetaheuristicOptions",
    "fit_ffrls",
    "fit_ffrls_hgwo",
    "fit_ls",
    "fit_metaheuristic",
    "fit_rls",
    "forgetting_factor",
    "hybrid_box",
    "itae_cost",
    "pole_radius",
    "recursive_least_squares",
    "regression_matrix",
    "simulate_population",
    "tustin_arx",
    "tustin_coefficients",
    "tustin_inverse",
]
