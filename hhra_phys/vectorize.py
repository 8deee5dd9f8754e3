"""SIMD across a population: CasADi's generated C with ``casadi_real`` a vector.

A population simulation runs the same straight-line arithmetic for every member.
CasADi generates scalar C, and no compiler vectorises it across calls. This module
recompiles CasADi's generated code as C++ with ``casadi_real`` defined as a small
struct holding ``width`` doubles (a GCC/Clang vector extension type), so every
arithmetic operation of the generated code advances ``width`` independent members
at once in SIMD registers. The generated code itself is untouched apart from the
bodies of CasADi's scalar helper functions (``casadi_sign``, ``casadi_fmin``, ...),
which are replaced by lane-wise versions, and the ``(c?x:0)`` form of ``if_else``.

Why this is safe: every operation defined on the vector type acts lane by lane
with the scalar semantics (IEEE division and square root are exact in both; other
mathematical functions call the same libm function per lane), so every lane gives
the scalar code's result bit for bit. The one exception is allowed by C99:
``fmin``/``fmax`` of two zeros of opposite sign may return the other zero. Any
construct of the generated code that would need a scalar decision (a branch or a
conversion to an integer) has no meaning for the vector type and fails to
*compile*, so a model outside what this supports falls back to scalar code
instead of giving a wrong answer. :data:`SUPPORTED_OPS` is checked first so that
fallback costs no compile.

Memory layout. Every element of every input, output and work array becomes
``width`` consecutive doubles: element ``e`` (CasADi's column-major order) of lane
``l`` is at ``e * width + l``.

The vector width is chosen from the C++ compiler's view of this machine
(``-march=native`` macros): 8 with AVX-512, 4 with AVX/AVX2, otherwise 2. Set
``HHRA_PHYS_SIMD`` to ``1`` (or ``off``) to disable, or to a width to force it.
"""

from __future__ import annotations

import functools
import os
import re
import shutil
import subprocess
from dataclasses import dataclass

import casadi as ca

__all__ = [
    "SimdTarget",
    "simd_target",
    "supports",
    "transform_source",
    "find_cxx",
]

#: SX operations the vector prelude implements lane by lane.
SUPPORTED_OPS: frozenset[int] = frozenset(
    getattr(ca, name)
    for name in (
        "OP_INPUT", "OP_OUTPUT", "OP_CONST", "OP_PARAMETER", "OP_ASSIGN",
        "OP_ADD", "OP_SUB", "OP_MUL", "OP_DIV", "OP_NEG", "OP_TWICE", "OP_INV",
        "OP_SQ", "OP_SQRT", "OP_EXP", "OP_LOG", "OP_POW", "OP_CONSTPOW",
        "OP_SIN", "OP_COS", "OP_TAN", "OP_ASIN", "OP_ACOS", "OP_ATAN", "OP_ATAN2",
        "OP_SINH", "OP_COSH", "OP_TANH", "OP_ASINH", "OP_ACOSH", "OP_ATANH",
        "OP_FABS", "OP_SIGN", "OP_COPYSIGN", "OP_FMIN", "OP_FMAX", "OP_FMOD",
        "OP_REMAINDER", "OP_FLOOR", "OP_CEIL", "OP_ERF", "OP_LOG1P", "OP_EXPM1",
        "OP_HYPOT", "OP_LT", "OP_LE", "OP_EQ", "OP_NE", "OP_NOT", "OP_AND", "OP_OR",
        "OP_IF_ELSE_ZERO",
    )
    if hasattr(ca, name)
)

#: C++ defining ``casadi_real`` as ``HV_W`` doubles with lane-wise semantics.
PRELUDE = r"""
#include <math.h>
/* C++ does not define it; CasADi's helpers then compile pre-C99 fallbacks (for
   example log(1+x) for log1p) which would round differently. With it, a helper
   this module does not replace calls a C99 function that has no vector
   overload, and fails to compile instead. */
#ifndef __STDC_VERSION__
#define __STDC_VERSION__ 199901L
#endif
#ifndef HV_W
#error "HV_W (the vector width) must be defined"
#endif
/* aligned(8): loads and stores need not be aligned to the vector size. */
typedef double hv_vec __attribute__((vector_size(HV_W * 8), aligned(8)));
typedef long long hv_ivec __attribute__((vector_size(HV_W * 8), aligned(8)));
struct hv_real {
  hv_vec v;
  hv_real() = default;
  hv_real(double d) { for (int i = 0; i < HV_W; ++i) v[i] = d; }
  explicit hv_real(hv_vec x) : v(x) {}
  hv_real& operator+=(hv_real o) { v += o.v; return *this; }
  hv_real& operator-=(hv_real o) { v -= o.v; return *this; }
  hv_real& operator*=(hv_real o) { v *= o.v; return *this; }
  hv_real& operator/=(hv_real o) { v /= o.v; return *this; }
};
static inline hv_real hv_select(hv_ivec m, hv_real a, hv_real b) { return hv_real(m ? a.v : b.v); }
static inline hv_real hv_mask(hv_ivec m) { return hv_select(m, hv_real(1.0), hv_real(0.0)); }
static inline hv_real operator+(hv_real a, hv_real b) { return hv_real(a.v + b.v); }
static inline hv_real operator-(hv_real a, hv_real b) { return hv_real(a.v - b.v); }
static inline hv_real operator*(hv_real a, hv_real b) { return hv_real(a.v * b.v); }
static inline hv_real operator/(hv_real a, hv_real b) { return hv_real(a.v / b.v); }
static inline hv_real operator-(hv_real a) { return hv_real(-a.v); }
static inline hv_real operator+(hv_real a) { return a; }
static inline hv_real operator<(hv_real a, hv_real b) { return hv_mask(a.v < b.v); }
static inline hv_real operator<=(hv_real a, hv_real b) { return hv_mask(a.v <= b.v); }
static inline hv_real operator>(hv_real a, hv_real b) { return hv_mask(a.v > b.v); }
static inline hv_real operator>=(hv_real a, hv_real b) { return hv_mask(a.v >= b.v); }
static inline hv_real operator==(hv_real a, hv_real b) { return hv_mask(a.v == b.v); }
static inline hv_real operator!=(hv_real a, hv_real b) { return hv_mask(a.v != b.v); }
static inline hv_real operator!(hv_real a) { return hv_mask(a.v == 0.0); }
static inline hv_real operator&&(hv_real a, hv_real b)
  { return hv_mask((a.v != 0.0) & (b.v != 0.0)); }
static inline hv_real operator||(hv_real a, hv_real b)
  { return hv_mask((a.v != 0.0) | (b.v != 0.0)); }
#define HV_UNARY(NAME, F) static inline hv_real NAME(hv_real a) \
  { hv_real r; for (int i = 0; i < HV_W; ++i) r.v[i] = F(a.v[i]); return r; }
#define HV_BINARY(NAME, F) static inline hv_real NAME(hv_real a, hv_real b) \
  { hv_real r; for (int i = 0; i < HV_W; ++i) r.v[i] = F(a.v[i], b.v[i]); return r; }
/* sqrt and fabs become single vector instructions (-fno-math-errno); the others
   call the scalar libm function per lane, exactly as the scalar code does. */
HV_UNARY(sqrt, __builtin_sqrt) HV_UNARY(fabs, __builtin_fabs)
HV_UNARY(exp, exp) HV_UNARY(log, log) HV_UNARY(sin, sin) HV_UNARY(cos, cos) HV_UNARY(tan, tan)
HV_UNARY(asin, asin) HV_UNARY(acos, acos) HV_UNARY(atan, atan) HV_UNARY(sinh, sinh)
HV_UNARY(cosh, cosh) HV_UNARY(tanh, tanh) HV_UNARY(asinh, asinh) HV_UNARY(acosh, acosh)
HV_UNARY(atanh, atanh) HV_UNARY(erf, erf) HV_UNARY(floor, floor) HV_UNARY(ceil, ceil)
HV_UNARY(hv_log1p, log1p) HV_UNARY(hv_expm1, expm1)
HV_BINARY(pow, pow) HV_BINARY(atan2, atan2) HV_BINARY(fmod, fmod)
HV_BINARY(remainder, remainder) HV_BINARY(copysign, copysign)
HV_BINARY(hv_hypot, hypot)
/* C99 fmin/fmax (a NaN argument yields the other one) as vector selects. */
static inline hv_real hv_fmax(hv_real a, hv_real b) {
  return hv_select(b.v != b.v, a, hv_select(a.v >= b.v, a, b));
}
static inline hv_real hv_fmin(hv_real a, hv_real b) {
  return hv_select(b.v != b.v, a, hv_select(a.v <= b.v, a, b));
}
static inline hv_real fmax(hv_real a, hv_real b) { return hv_fmax(a, b); }
static inline hv_real fmin(hv_real a, hv_real b) { return hv_fmin(a, b); }
static inline hv_real hv_sq(hv_real x) { return x * x; }
static inline hv_real hv_fabs(hv_real x) { return fabs(x); }
static inline hv_real hv_sign(hv_real x) {
  /* x<0 ? -1 : x>0 ? 1 : x, lane by lane (keeps NaN and signed zero). */
  return hv_select(x.v < 0.0, hv_real(-1.0), hv_select(x.v > 0.0, hv_real(1.0), x));
}
static inline hv_real hv_if_else_zero(hv_real c, hv_real x) {
  return hv_select(c.v != 0.0, x, hv_real(0.0));
}
#define casadi_real hv_real
"""

# A scalar helper of CasADi's generated code: one line, or a body ending at "}".
_HELPER = re.compile(
    r"^casadi_real casadi_(\w+)\(casadi_real x(, casadi_real y)?\) \{(?:[^\n]*\}$|.*?^\}$)",
    re.M | re.S,
)
# SX if_else_zero is printed as "(c?x:0)" with two work variables.
_IF_ELSE_ZERO = re.compile(r"\((\w+)\?(\w+):0\)")


def transform_source(source: str) -> str:
    """CasADi-generated C -> C++ evaluating ``HV_W`` lanes per call.

    Replaces the bodies of the scalar helpers by the prelude's lane-wise versions
    and SX ``if_else`` by a lane-wise select; everything else is kept verbatim.
    """

    def helper(match: re.Match[str]) -> str:
        name, two = match.group(1), match.group(2)
        args = "x, y" if two else "x"
        return (f"casadi_real casadi_{name}(casadi_real x{', casadi_real y' if two else ''}) "
                f"{{ return hv_{name}({args}); }}")

    body = _HELPER.sub(helper, source)
    body = _IF_ELSE_ZERO.sub(r"hv_if_else_zero(\1,\2)", body)
    return PRELUDE + body


def supports(fn: ca.Function) -> bool:
    """Whether every operation of the SX function ``fn`` has a lane-wise version."""
    if not fn.is_a("SXFunction"):
        return False
    return all(fn.instruction_id(k) in SUPPORTED_OPS for k in range(fn.n_instructions()))


@dataclass(frozen=True)
class SimdTarget:
    """How to compile vectorised code on this machine.

    Attributes
    ----------
    width : int
        Doubles per vector (members simulated together).
    compiler : str
        The C++ compiler.
    flags : tuple of str
        Instruction-set flags for that width (e.g. ``-mavx512f``).
    """

    width: int
    compiler: str
    flags: tuple[str, ...]


def find_cxx() -> str | None:
    """The C++ compiler: ``$CXX``, else ``c++``, ``g++`` or ``clang++`` on the PATH."""
    for cand in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if cand and shutil.which(cand):
            return cand
    return None


def _native_macros(cxx: str) -> str:
    try:
        proc = subprocess.run(
            [cxx, "-march=native", "-dM", "-E", "-x", "c++", os.devnull],
            capture_output=True, text=True, timeout=60,
        )
    except (OSError, subprocess.SubprocessError):
        return ""
    return proc.stdout if proc.returncode == 0 else ""


@functools.cache
def _detect(cxx: str) -> tuple[int, tuple[str, ...]]:
    macros = _native_macros(cxx)
    # Explicit ISA flags rather than -march=native: the cache key then names the
    # instruction set, and -march=native may prefer narrower vectors on AVX-512 parts.
    if "__AVX512F__" in macros:
        return 8, ("-mavx512f",)
    if "__AVX2__" in macros:
        return 4, ("-mavx2",)
    if "__AVX__" in macros:
        return 4, ("-mavx",)
    return 2, ()  # SSE2 (x86-64) and NEON (AArch64) are baseline


def simd_target() -> SimdTarget | None:
    """The SIMD configuration for this machine, or ``None`` when disabled or impossible.

    ``HHRA_PHYS_SIMD`` overrides the detected width (``1``/``off`` disables).
    """
    setting = os.environ.get("HHRA_PHYS_SIMD", "auto").strip().lower()
    if setting in ("0", "1", "off", "no", "false"):
        return None
    cxx = find_cxx()
    if cxx is None:
        return None
    width, flags = _detect(cxx)
    if setting not in ("", "auto"):
        try:
            forced = int(setting)
        except ValueError as exc:
            raise ValueError(
                f"HHRA_PHYS_SIMD must be 'auto', 'off' or a vector width, got {setting!r}"
            ) from exc
        if forced < 1 or forced & (forced - 1):
            raise ValueError(f"HHRA_PHYS_SIMD width must be a power of two, got {forced}")
        if forced == 1:
            return None
        width = forced  # wider than the registers: the compiler splits the vectors
    return SimdTarget(width, cxx, flags)
