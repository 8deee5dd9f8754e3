"""The nine benchmark functions of the reference paper's Table 1, vectorised over populations.

Every function maps an ``(n, d)`` array of points to ``(n,)`` costs. :func:`get_benchmark`
wraps one of them with its box, dimension and known minimum in a :class:`Benchmark`, and
builds the *shifted* variants used to check for a bias toward the coordinate origin.

Corrections to the paper's Table 1 (``docs/model.md``, "The paper's errata and our readings"):

* f5 Ackley keeps the printed range [-30, 30] (the usual suite has [-32, 32]);
* f6 Griewank uses ``1/4000`` (the paper prints ``1/40000``);
* f8 Kowalik squares the residuals (the paper drops the square);
* f3's noise is ``uniform[0, 1)`` per evaluated point, drawn from a seeded generator; its
  minimum value 0 is the noise-free minimum (the infimum of the noisy function).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from hhra_phys.errors import ParameterError

__all__ = [
    "sphere",
    "rosenbrock",
    "quartic",
    "rastrigin",
    "ackley",
    "griewank",
    "six_hump_camel",
    "kowalik",
    "goldstein_price",
    "Benchmark",
    "get_benchmark",
]

#: Kowalik's data (a_i and 1/b_i) as in the usual suite.
KOWALIK_A = np.array(
    [0.1957, 0.1947, 0.1735, 0.1600, 0.0844, 0.0627, 0.0456, 0.0342, 0.0323, 0.0235, 0.0246]
)
KOWALIK_B = 1.0 / np.array([0.25, 0.5, 1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0])


def sphere(x: np.ndarray) -> np.ndarray:
    """f1: ``sum x_i^2``."""
    return np.einsum("ij,ij->i", x, x)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    """f2: ``sum 100 (x_{i+1} - x_i^2)^2 + (x_i - 1)^2``."""
    a, b = x[:, :-1], x[:, 1:]
    return np.sum(100.0 * (b - a * a) ** 2 + (a - 1.0) ** 2, axis=1)


def quartic(x: np.ndarray) -> np.ndarray:
    """f3 without its noise: ``sum i * x_i^4``."""
    x2 = x * x
    return (x2 * x2) @ np.arange(1.0, x.shape[1] + 1.0)


def rastrigin(x: np.ndarray) -> np.ndarray:
    """f4: ``sum x_i^2 - 10 cos(2 pi x_i) + 10``."""
    return np.sum(x * x - 10.0 * np.cos(2.0 * np.pi * x) + 10.0, axis=1)


def ackley(x: np.ndarray) -> np.ndarray:
    """f5: ``-20 exp(-0.2 sqrt(mean x^2)) - exp(mean cos(2 pi x)) + 20 + e``."""
    r = np.sqrt(np.mean(x * x, axis=1))
    c = np.mean(np.cos(2.0 * np.pi * x), axis=1)
    return -20.0 * np.exp(-0.2 * r) - np.exp(c) + 20.0 + np.e


def griewank(x: np.ndarray) -> np.ndarray:
    """f6: ``sum x_i^2 / 4000 - prod cos(x_i / sqrt(i)) + 1``."""
    i = np.sqrt(np.arange(1.0, x.shape[1] + 1.0))
    return np.einsum("ij,ij->i", x, x) / 4000.0 - np.prod(np.cos(x / i), axis=1) + 1.0


def six_hump_camel(x: np.ndarray) -> np.ndarray:
    """f7: ``4x1^2 - 2.1x1^4 + x1^6/3 + x1 x2 - 4x2^2 + 4x2^4``."""
    a, b = x[:, 0], x[:, 1]
    a2, b2 = a * a, b * b
    return 4.0 * a2 - 2.1 * a2 * a2 + a2 * a2 * a2 / 3.0 + a * b - 4.0 * b2 + 4.0 * b2 * b2


def kowalik(x: np.ndarray) -> np.ndarray:
    """f8: ``sum (a_i - x1 (b_i^2 + b_i x2) / (b_i^2 + b_i x3 + x4))^2``.

    Where a denominator vanishes the cost is not finite (the optimisers treat it as worst).
    """
    b = KOWALIK_B
    num = x[:, :1] * (b * b + b * x[:, 1:2])
    den = b * b + b * x[:, 2:3] + x[:, 3:4]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        r = KOWALIK_A - num / den
        return np.sum(r * r, axis=1)


def goldstein_price(x: np.ndarray) -> np.ndarray:
    """f9: Goldstein-Price function."""
    a, b = x[:, 0], x[:, 1]
    t1 = 1.0 + (a + b + 1.0) ** 2 * (
        19.0 - 14.0 * a + 3.0 * a * a - 14.0 * b + 6.0 * a * b + 3.0 * b * b
    )
    t2 = 30.0 + (2.0 * a - 3.0 * b) ** 2 * (
        18.0 - 32.0 * a + 12.0 * a * a + 48.0 * b - 36.0 * a * b + 27.0 * b * b
    )
    return t1 * t2


@dataclass(frozen=True)
class _Spec:
    name: str
    group: str
    func: Callable[[np.ndarray], np.ndarray]
    dim: int
    lower: float
    upper: float
    f_min: float
    x_min: tuple[float, ...]  # one global minimiser (length 1 = same value in every dimension)
    noisy: bool = False


_SPECS: dict[str, _Spec] = {
    "f1": _Spec("sphere", "unimodal", sphere, 30, -100.0, 100.0, 0.0, (0.0,)),
    "f2": _Spec("Rosenbrock", "unimodal", rosenbrock, 30, -30.0, 30.0, 0.0, (1.0,)),
    "f3": _Spec("quartic with noise", "unimodal", quartic, 30, -1.28, 1.28, 0.0, (0.0,), True),
    "f4": _Spec("Rastrigin", "multimodal", rastrigin, 30, -5.12, 5.12, 0.0, (0.0,)),
    "f5": _Spec("Ackley", "multimodal", ackley, 30, -30.0, 30.0, 0.0, (0.0,)),
    "f6": _Spec("Griewank", "multimodal", griewank, 30, -600.0, 600.0, 0.0, (0.0,)),
    # two minimisers, +-(0.0898, -0.7127); values from a Newton solve
    "f7": _Spec(
        "six-hump camel back",
        "fixed-dimension",
        six_hump_camel,
        2,
        -5.0,
        5.0,
        -1.0316284534898772,
        (0.08984201387491801, -0.7126564029734865),
    ),
    # least-squares solve; no lower point exists in [-10, 10]^4 (checked by multistart)
    "f8": _Spec(
        "Kowalik",
        "fixed-dimension",
        kowalik,
        4,
        -5.0,
        5.0,
        3.074859878056055e-4,
        (0.19283345240281755, 0.19083625557244804, 0.12311730117010533, 0.13576599756413274),
    ),
    "f9": _Spec(
        "Goldstein-Price", "fixed-dimension", goldstein_price, 2, -2.0, 2.0, 3.0, (0.0, -1.0)
    ),
}

#: Keys of the nine functions, in the paper's order.
BENCHMARK_KEYS: tuple[str, ...] = tuple(_SPECS)

#: Fraction of the box width kept free at each side when a shifted optimum is drawn.
SHIFT_MARGIN = 0.1


@dataclass(frozen=True)
class Benchmark:
    """One benchmark function with its box and known minimum; call it on points.

    Attributes
    ----------
    key, name, group : str
        ``"f1"`` ..., the usual name, and the paper's group.
    dim : int
        Dimension ``d``.
    lower, upper : float
        The box ``[lower, upper]^d``.
    f_min : float
        Known minimum value (for f3: of the noise-free part).
    x_min : numpy.ndarray
        A global minimiser, shape ``(d,)``, inside the box (shifted variants included).
    shift : numpy.ndarray
        ``s`` such that this function is ``f(x - s)`` of the original; zero unless shifted.
    noise_rng : numpy.random.Generator or None
        Source of f3's noise; ``None`` for noise-free functions.
    """

    key: str
    name: str
    group: str
    dim: int
    lower: float
    upper: float
    f_min: float
    x_min: np.ndarray
    shift: np.ndarray
    func: Callable[[np.ndarray], np.ndarray] = field(repr=False)
    noise_rng: np.random.Generator | None = field(default=None, repr=False)
    _shifted: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # cached: __call__ sits in every optimiser's inner loop
        object.__setattr__(self, "_shifted", bool(np.any(self.shift != 0.0)))

    @property
    def bounds(self) -> list[tuple[float, float]]:
        """The box as ``[(lower, upper)] * dim``."""
        return [(self.lower, self.upper)] * self.dim

    @property
    def is_shifted(self) -> bool:
        """Whether the optimum has been moved."""
        return self._shifted

    def __call__(self, x: np.ndarray) -> np.ndarray | float:
        """Costs of points: ``(n, d)`` gives ``(n,)``, a single ``(d,)`` vector gives a float."""
        arr = np.asarray(x, dtype=float)
        single = arr.ndim == 1
        pts = arr[None, :] if single else arr
        if pts.ndim != 2 or pts.shape[1] != self.dim:
            raise ParameterError(
                f"x: {self.key} expects points of shape (n, {self.dim}), got {arr.shape}"
            )
        out = self.func(pts - self.shift if self._shifted else pts)
        if self.noise_rng is not None:
            out = out + self.noise_rng.random(out.shape[0])
        return float(out[0]) if single else out

    def noise_free(self) -> Benchmark:
        """The same function without noise (for checks at the optimum)."""
        return replace(self, noise_rng=None)

    def shifted(self, seed: int | np.random.Generator | None) -> Benchmark:
        """The same function with its optimum moved to a seeded random point of the box.

        The point ``o`` is uniform in the box less a margin of 10 % of the width at each side
        (so the optimum is neither at the origin nor on the boundary), and the function
        becomes ``g(x) = f(x - s)`` with ``s = o - x_min``: its minimiser is ``o`` and its
        minimum value is unchanged. The box stays the same, so ``g`` sees a part of ``f``'s
        domain up to one box width away; for every function here the minimum over that
        larger region is the same value (f7's second minimiser may move out of the box, f8 was
        checked on [-10, 10]^4, f9's factors are bounded below by 1 and 3 everywhere).
        f3's noise generator is shared with this function.
        """
        rng = np.random.default_rng(seed)
        margin = SHIFT_MARGIN * (self.upper - self.lower)
        o = rng.uniform(self.lower + margin, self.upper - margin, self.dim)
        base_min = self.x_min - self.shift
        return replace(self, x_min=o, shift=o - base_min)


def get_benchmark(
    key: str,
    *,
    seed: int | np.random.Generator | None = None,
    shift_seed: int | np.random.Generator | None = None,
) -> Benchmark:
    """One of the nine functions, optionally shifted.

    Parameters
    ----------
    key : {"f1", ..., "f9"}
        The function (paper's numbering).
    seed : int, Generator or None
        Seed of f3's noise (ignored by the other functions).
    shift_seed : int, Generator or None
        If given, return the shifted variant with its optimum at a point drawn from this seed
        (see :meth:`Benchmark.shifted`).

    Raises
    ------
    ParameterError
        If ``key`` is not one of :data:`BENCHMARK_KEYS`.
    """
    if key not in _SPECS:
        raise ParameterError(f"key: expected one of {list(BENCHMARK_KEYS)}, got {key!r}")
    s = _SPECS[key]
    x_min = np.broadcast_to(np.asarray(s.x_min, dtype=float), (s.dim,)).copy()
    bench = Benchmark(
        key=key,
        name=s.name,
        group=s.group,
        dim=s.dim,
        lower=s.lower,
        upper=s.upper,
        f_min=s.f_min,
        x_min=x_min,
        shift=np.zeros(s.dim),
        func=s.func,
        noise_rng=np.random.default_rng(seed) if s.noisy else None,
    )
    return bench if shift_seed is None else bench.shifted(shift_seed)
