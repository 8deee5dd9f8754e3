"""Records with a resonance the model lacks, from the independent reference rig.

Truth for the tests and study of the discovered mode
(:class:`hhra_phys.discover.DiscoveredMode`). Nothing here imports the package's
model code or the mode's code.

* :func:`resonant_record`: the noise-free angle of the independent reference model
  (:func:`hhra_phys.reference.outside.outside_record` with no extra term,
  NumPy/SciPy, ``solve_ivp``) passed through a second-order filter
  ``H(s) = w^2/(s^2 + 2 z w s + w^2)`` (a compliant coupling between shaft and
  encoder, or a resonant sensor) by :func:`scipy.signal.lsim`, then noise.
* :func:`loaded_record`: the reference model's shaft carries a second inertia on a
  compliant coupling (a load on a flexible arm); the encoder reads the actuator's
  angle. Absolute states ``[theta, omega, p, theta_l, omega_l]``, integrated by
  ``solve_ivp`` under an exact zero-order hold::

      torque of the coupling over the actuator's inertia:
          c = ratio*(w^2*(theta - theta_l) + 2*z*w*(omega - omega_l))
      domega/dt   = (reference rate of omega) - c
      dtheta_l/dt = omega_l
      domega_l/dt = c/ratio

* :func:`multisine_resonator_record`: a lightly damped resonator (not the HHRA)
  driven by a *continuous* multisine, integrated by ``solve_ivp`` with the input
  evaluated at every instant the integrator asks for, then sampled at a few
  samples per resonance period: the input really moves between samples, which
  neither a zero-order nor a first-order hold reproduces exactly. Optionally a
  hidden cubic stiffening of the spring::

      dx/dt = v
      dv/dt = w^2 (gain u(t) - x - cubic x^3) - 2 zeta w v,    y = x + noise
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal as sps
from scipy.integrate import solve_ivp

from hhra_phys.data import Dataset
from hhra_phys.reference.hhra import REFERENCE_GROUPS, reference_record, reference_rhs
from hhra_phys.reference.outside import integrate_held, outside_record

__all__ = ["resonant_record", "loaded_record", "multisine_resonator_record"]


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


def loaded_record(period: float, ratio: float, damping: float, seed: int = 0,
                  duration: float = 6.0, fs: float = 250.0, noise_deg: float = 0.05,
                  levels: int = 4) -> Dataset:
    """A rig record (angle [deg] from current [mA]) whose shaft carries a compliant load.

    Parameters
    ----------
    period : float
        Natural period ``2 pi / w`` of the load on its coupling (actuator held) [s].
    ratio : float
        Load inertia over the actuator's inertia [-] (> 0).
    damping : float
        Damping ratio ``z`` of the coupling [-].
    seed : int
        Seeds the excitation (as :func:`~hhra_phys.reference.hhra.reference_record`)
        and the noise.
    duration, fs : float
        Length [s] and sample rate [Hz].
    noise_deg : float
        Standard deviation of the angle noise [deg].
    levels : int
        Amplitude levels of the excitation.

    Returns
    -------
    Dataset
        ``metadata["truth"]`` holds ``period``, ``w`` [rad/s], ``ratio``, ``damping``, the
        reference groups ``params`` and the initial state ``x0`` of the actuator.
    """
    if not all(math.isfinite(v) and v > 0 for v in (period, ratio, damping)):
        raise ValueError(f"period, ratio and damping must be > 0, got {period}, {ratio}, "
                         f"{damping}")
    base = reference_record(seed=seed, duration=duration, fs=fs, noise_deg=0.0, levels=levels)
    u = base.u
    params = {k: v for k, v in REFERENCE_GROUPS.items() if k != "g_kp"}
    x0 = [base.metadata["x0"][n] for n in ("theta", "omega", "p")]
    # The load starts with the shaft, untwisted.
    x = np.array([*x0, x0[0], x0[1]], dtype=float)
    w = 2 * math.pi / period

    def rhs(_t: float, xx: np.ndarray, uk: float) -> np.ndarray:
        d = np.empty(5)
        d[:3] = reference_rhs(xx[:3], uk, params)
        c = ratio * (w * w * (xx[0] - xx[3]) + 2 * damping * w * (xx[1] - xx[4]))
        d[1] -= c
        d[3] = xx[4]
        d[4] = c / ratio
        return d

    X = integrate_held(rhs, x, u, fs, "loaded_record")
    rng = np.random.default_rng([seed, 3])
    y = np.degrees(X[:, 0]) + noise_deg * rng.standard_normal(u.size)
    meta = {"generator": "hhra_phys.reference.resonant.loaded_record", "seed": seed,
            "noise_deg": noise_deg,
            "truth": {"period": period, "w": w, "ratio": ratio, "damping": damping,
                      "params": params, "x0": dict(zip(("theta", "omega", "p"), x0, strict=True))}}
    return Dataset.from_arrays(u, y, fs=fs, metadata=meta,
                               name=f"loaded-{period:g}s-{ratio:g}-seed{seed}",
                               input_name="current", input_unit="mA", output_name="angle",
                               output_unit="deg")


def multisine_resonator_record(seed: int = 1, samples_per_period: float = 9.0,
                               periods: float = 240.0, f_n: float = 10.0, zeta: float = 0.05,
                               gain: float = 1.0, cubic: float = 0.0, amplitude: float = 1.0,
                               band: float = 2.0, lines: int = 60,
                               noise: float = 0.01) -> Dataset:
    """A resonator driven by a continuous multisine, sampled coarsely (truth for foh studies).

    Parameters
    ----------
    seed : int
        Seeds the multisine's phases and the noise.
    samples_per_period : float
        Sample rate over the natural frequency, ``fs / f_n`` (8 to 10 is the regime
        where holding the input between samples is visibly wrong).
    periods : float
        Length of the record in resonance periods (``N = periods * samples_per_period``).
    f_n : float
        Natural frequency [Hz] (``w = 2 pi f_n``).
    zeta : float
        Damping ratio [-].
    gain : float
        Static gain [V/V].
    cubic : float
        Hidden cubic stiffening [1/V^2]: the spring force is ``w^2 (x + cubic x^3)``;
        0 for a linear resonator.
    amplitude : float
        RMS of the input [V].
    band : float
        Highest line of the multisine over ``f_n``; the lines are ``lines`` equally spaced
        frequencies from ``band*f_n/lines`` to ``band*f_n``, of equal amplitude and random
        phases.
    lines : int
        Number of sine lines.
    noise : float
        Standard deviation of the white output noise [V].

    Returns
    -------
    Dataset
        Input and output [V] at ``fs = samples_per_period * f_n``. The record carries no
        inter-sample property (it reads as ``"zoh"``, as a plain CSV would);
        ``metadata["truth"]`` holds the physics, the multisine and ``"input": "continuous"``.

    Notes
    -----
    The integration uses the multisine itself, not its samples (``DOP853``, rtol 1e-10,
    steps at most a twentieth of a resonance period), so the record is what a continuous
    input would give; nothing here imports the package's model code.
    """
    values = (samples_per_period, periods, f_n, zeta, gain, amplitude, band)
    if not all(math.isfinite(v) and v > 0 for v in values):
        raise ValueError("samples_per_period, periods, f_n, zeta, gain, amplitude and band "
                         f"must be positive, got {values}")
    if not (math.isfinite(cubic) and cubic >= 0 and math.isfinite(noise) and noise >= 0):
        raise ValueError(f"cubic and noise must be finite and >= 0, got {cubic}, {noise}")
    if int(lines) < 1:
        raise ValueError(f"lines must be a positive integer, got {lines}")
    rng = np.random.default_rng([seed, 22])
    freqs = band * f_n * np.arange(1, int(lines) + 1) / int(lines)
    phases = rng.uniform(0.0, 2 * math.pi, freqs.size)
    amp = amplitude * math.sqrt(2.0 / freqs.size)
    w = 2 * math.pi * f_n
    fs = samples_per_period * f_n
    n = int(round(periods * samples_per_period))
    t = np.arange(n) / fs
    omega = 2 * math.pi * freqs

    def u_of(tt: np.ndarray | float) -> np.ndarray:
        return amp * np.cos(np.multiply.outer(tt, omega) + phases).sum(axis=-1)

    def rhs(tt: float, xx: np.ndarray) -> np.ndarray:
        x, v = xx
        return np.array([v, w * w * (gain * float(u_of(tt)) - x - cubic * x ** 3)
                         - 2 * zeta * w * v])

    sol = solve_ivp(rhs, (0.0, float(t[-1])), np.zeros(2), t_eval=t, method="DOP853",
                    rtol=1e-10, atol=1e-12, max_step=1.0 / (20 * f_n))
    if not sol.success:
        raise RuntimeError(f"multisine_resonator_record: integration failed: {sol.message}")
    y = sol.y[0] + noise * rng.standard_normal(n)
    meta = {"generator": "hhra_phys.reference.resonant.multisine_resonator_record",
            "seed": seed, "noise": noise,
            "truth": {"input": "continuous", "f_n": f_n, "w_n": w, "zeta": zeta, "gain": gain,
                      "cubic": cubic, "samples_per_period": samples_per_period,
                      "multisine": {"frequencies": freqs.tolist(), "phases": phases.tolist(),
                                    "amplitude": amp}}}
    return Dataset.from_arrays(u_of(t), y, fs=fs, metadata=meta,
                               name=f"multisine-resonator-{samples_per_period:g}-seed{seed}",
                               input_name="drive", input_unit="V", output_name="response",
                               output_unit="V")
