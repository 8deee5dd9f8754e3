"""The Tustin image of the paper's continuous model, and back.

:func:`tustin_coefficients` discretises ``G(s) = k_v / (a s^3 + b s^2 + c s)`` with the
bilinear map (the paper's eq. 12 with its slip corrected), :func:`tustin_arx` gives it as an
:class:`~hhra_phys.arx.structure.ARXModel`, and :func:`tustin_inverse` recovers the
continuous coefficients from a discrete model. Separate from the ARX structure: it links the
black-box path to the physical model's transfer function and nothing else needs it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hhra_phys.arx.structure import ARXModel
from hhra_phys.errors import ParameterError

__all__ = ["tustin_arx", "tustin_coefficients", "tustin_inverse"]


def tustin_coefficients(
    a: float, b: float, c: float, kv: float, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Tustin (bilinear) discretisation of ``G(s) = kv / (a s^3 + b s^2 + c s)``.

    With ``s = (2/T)(z-1)/(z+1)`` and ``T = dt`` (the paper's eq. 12 with its slip corrected)::

        G(z) = kv (z+1)^3 / [ (8a/T^3)(z-1)^3 + (4b/T^2)(z-1)^2(z+1) + (2c/T)(z-1)(z+1)^2 ]

    normalised so that the leading denominator coefficient is 1. The denominator has a root at
    ``z = 1`` (the integrator) and the numerator a direct feed-through ``b_0``, so the exact image
    is an ARX model with ``na = 3, nb = 4, nk = 0`` (see :func:`tustin_arx`), not the paper's
    eq. 13 structure (``nb = 3, nk = 1``).

    Parameters
    ----------
    a, b, c : float
        Denominator coefficients [s^3], [s^2], [s] times a common scale (e.g. ``a = 1``).
    kv : float
        Numerator in the same scale [output unit / input unit], e.g. rad/mA.
    dt : float
        Sample period T [s].

    Returns
    -------
    num, den : numpy.ndarray, shape (4,)
        ``num = [b_0, b_1, b_2, b_3]`` and ``den = [1, a_1, a_2, a_3]``: coefficients of
        ascending powers of ``z^-1`` (equally, descending powers of ``z``); the same as
        ``scipy.signal.cont2discrete(..., method='bilinear')``.
    """
    for name, value in (("a", a), ("b", b), ("c", c), ("kv", kv)):
        if not np.isfinite(value):
            raise ParameterError(f"{name} must be finite, got {value!r}")
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt must be a positive sample period in s, got {dt!r}")
    big_a, big_b, big_c = 8.0 * a / dt**3, 4.0 * b / dt**2, 2.0 * c / dt
    # (z-1)^3, (z-1)^2 (z+1), (z-1)(z+1)^2 in descending powers of z.
    den = big_a * np.array([1.0, -3.0, 3.0, -1.0])
    den += big_b * np.array([1.0, -1.0, -1.0, 1.0])
    den += big_c * np.array([1.0, 1.0, -1.0, -1.0])
    if den[0] == 0.0:
        raise ParameterError("8a/T^3 + 4b/T^2 + 2c/T is zero: the Tustin image is not proper")
    num = kv * np.array([1.0, 3.0, 3.0, 1.0])
    return num / den[0], den / den[0]


# Maps [8a/T^3, 4b/T^2, 2c/T] to the Tustin denominator (columns as in tustin_coefficients).
_TUSTIN_DEN = np.array([[1.0, 1.0, 1.0], [-3.0, -1.0, 1.0], [3.0, -1.0, -1.0], [-1.0, 1.0, -1.0]])
_TUSTIN_NUM = np.array([1.0, 3.0, 3.0, 1.0])


def tustin_inverse(num: Any, den: Any, dt: float, rtol: float = 1e-6) -> dict[str, float]:
    """Continuous ``a, b, c, kv`` whose Tustin image is the discrete ``num / den``.

    The inverse exists only when the discrete model has the Tustin image's structure: a
    denominator ``[d_0, d_1, d_2, d_3]`` with a root at ``z = 1`` (``sum(den) = 0``) and a
    numerator proportional to ``(1 + z^-1)^3``. Both conditions are checked with relative
    tolerance ``rtol``; the continuous coefficients are then the least-squares solution of the
    linear map of :func:`tustin_coefficients`. A fitted eq.-13 ARX (``b_0 = 0``, no forced
    integrator) is generally not such an image: pass ``rtol=numpy.inf`` to get the nearest
    continuous coefficients anyway (denominator and numerator projected separately), and read
    the deviations in the error message of the strict call to know how far off they are.

    Parameters
    ----------
    num, den : array_like, shape (4,)
        Coefficients of ascending powers of ``z^-1`` (``den[0] != 0``).
    dt : float
        Sample period T [s].
    rtol : float
        Relative tolerance of the structure checks.

    Returns
    -------
    dict
        ``{"a": 1.0, "b": .., "c": .., "kv": ..}`` normalised to ``a = 1`` (as
        :meth:`hhra_phys.model.HHRAModel.tf_coefficients`): ``b`` [1/s], ``c`` [1/s^2], ``kv``
        [output unit / (input unit s^3)]; plus ``den_deviation`` and ``num_deviation``, the
        relative deviations of the two structure checks.

    Raises
    ------
    ParameterError
        If ``num``/``den`` do not have 4 finite coefficients, or the structure checks fail (the
        message gives the deviations), or the fitted ``a`` is zero.
    """
    n = np.asarray(num, dtype=float).ravel()
    d = np.asarray(den, dtype=float).ravel()
    if n.shape != (4,) or d.shape != (4,) or not (np.isfinite(n).all() and np.isfinite(d).all()):
        raise ParameterError(
            f"num and den must each hold 4 finite coefficients (z^0..z^-3), got {n} and {d}"
        )
    if d[0] == 0.0:
        raise ParameterError("den[0] must be non-zero")
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt must be a positive sample period in s, got {dt!r}")
    n, d = n / d[0], d / d[0]
    abc, *_ = np.linalg.lstsq(_TUSTIN_DEN, d, rcond=None)
    den_dev = float(np.linalg.norm(_TUSTIN_DEN @ abc - d) / np.linalg.norm(d))
    gain = float(n @ _TUSTIN_NUM / (_TUSTIN_NUM @ _TUSTIN_NUM))
    scale = np.linalg.norm(n)
    num_dev = float(np.linalg.norm(n - gain * _TUSTIN_NUM) / scale) if scale > 0 else 0.0
    if den_dev > rtol or num_dev > rtol:
        raise ParameterError(
            "num/den is not the Tustin image of kv/(a s^3 + b s^2 + c s): relative deviation of "
            f"the denominator from one with a root at z = 1: {den_dev:.3g}, of the numerator from "
            f"kv*(1 + z^-1)^3: {num_dev:.3g} (rtol = {rtol:g}); pass rtol=numpy.inf for the "
            "nearest continuous coefficients"
        )
    a = abc[0] * dt**3 / 8.0
    if a == 0.0:
        raise ParameterError("the continuous s^3 coefficient is zero; cannot normalise to a = 1")
    return {
        "a": 1.0,
        "b": float(abc[1] * dt**2 / 4.0 / a),
        "c": float(abc[2] * dt / 2.0 / a),
        "kv": float(gain / a),
        "den_deviation": den_dev,
        "num_deviation": num_dev,
    }


def tustin_arx(a: float, b: float, c: float, kv: float, dt: float) -> ARXModel:
    """The exact Tustin image of ``kv / (a s^3 + b s^2 + c s)`` as an ARX(3, 4, 0) model."""
    num, den = tustin_coefficients(a, b, c, kv, dt)
    return ARXModel(den[1:], num, nk=0)
