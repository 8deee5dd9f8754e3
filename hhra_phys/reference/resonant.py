"""Records with a resonance the model lacks: the reference rig read through a resonant sensor.

Truth for the tests and study of the discovered mode
(:class:`hhra_phys.discover.DiscoveredMode`): the noise-free angle of the
independent reference model (:func:`hhra_phys.reference.outside.outside_record`
with no extra term, NumPy/SciPy, ``solve_ivp``) passed through a second-order
filter ``H(s) = w^2/(s^2 + 2 z w s + w^2)`` (a compliant coupling between shaft
and encoder, or a resonant sensor) by :func:`scipy.signal.lsim`, then noise is
added. Nothing here imports the package's model code or the mode's code.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal as sps

from hhra_phys.data import Dataset
from hhra_phys.reference.outside import outside_record

__all__ = ["resonant_record"]


def resonant_record(period: float, damping: float, seed: int = 0, duration: float = 6.0,
                    fs: float = 250.0, noise_deg: float = 0.05, levels: int = 4) -> Dataset:
    """A rig record (angle [deg] from current [mA]) seen through a resonant sensor.

    Parameters
    ----------
    period : float
        Natural period ``2 pi / w`` of the sensor's resonance [s]; 0 for none
        (a clean record).
    damping : float
        Damping ratio ``z`` of the resonance [-].
    seed : int
        Seeds the excitation and the noise (as :func:`outside_record`).
    duration, fs : float
        Length [s] and sample rate [Hz].
    noise_deg : float
        Standard deviation of the angle noise [deg].
    levels : int
        Amplitude levels of the excitation.

    Returns
    -------
    Dataset
        ``metadata["truth"]`` holds ``period``, ``w`` [rad/s] and ``damping``.
    """
    if not (math.isfinite(period) and period >= 0 and math.isfinite(damping) and damping > 0):
        raise ValueError(f"period must be >= 0 and damping > 0, got {period}, {damping}")
    base = outside_record("none", 0.0, seed=seed, duration=duration, fs=fs, noise_deg=0.0,
                          levels=levels)
    y = np.asarray(base.y, dtype=float)
    w = 2 * math.pi / period if period > 0 else math.inf
    if period > 0:
        t = np.arange(base.n) / fs
        # The sensor starts at rest on the first angle (the filter of y - y[0]).
        _, yf, _ = sps.lsim(([w * w], [1.0, 2 * damping * w, w * w]), y - y[0], t)
        y = np.asarray(yf, dtype=float) + y[0]
    rng = np.random.default_rng([seed, 2])
    y = y + noise_deg * rng.standard_normal(base.n)
    meta = {"generator": "hhra_phys.reference.resonant", "seed": seed, "noise_deg": noise_deg,
            "truth": {"period": period, "w": w, "damping": damping}}
    return Dataset.from_arrays(base.u, y, fs=fs, metadata=meta,
                               name=f"resonant-{period:g}s-seed{seed}", input_name="current",
                               input_unit="mA", output_name="angle", output_unit="deg")
