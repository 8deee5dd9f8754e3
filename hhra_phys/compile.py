"""Compile CasADi functions to native code and call them without copies.

CasADi's own Python call converts every array element by element, which for a
population of 100 trajectories of 5000 samples costs more than the simulation.
This module generates C with :class:`casadi.CodeGenerator`, compiles it once with
the machine's C compiler into a cache directory (keyed by a hash of the source
and the flags, so every later process reuses it), and calls the function through
:mod:`ctypes` on NumPy buffers. CasADi's thread map is generated as POSIX
threads, so the population runs in parallel inside one call with the GIL
released.

When no C compiler is found (or compilation fails) :func:`compile_function`
returns ``None`` and callers fall back to CasADi's virtual machine, which gives
the same numbers more slowly.

``compile_function(fn, simd=target)`` compiles the same generated code with
``casadi_real`` a vector of ``target.width`` doubles (:mod:`hhra_phys.vectorize`):
one call then evaluates ``width`` independent instances, one per SIMD lane.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
import warnings
from collections.abc import Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from hhra_phys.errors import ModelError
from hhra_phys.vectorize import SimdTarget, transform_source

__all__ = [
    "cache_dir",
    "find_compiler",
    "CompiledFunction",
    "compile_function",
    "MAX_SOURCE_BYTES",
]

#: Flags for the generated code. No -ffast-math: it would let the compiler drop
#: the NaN/Inf propagation that flags diverging population members. No FMA
#: contraction (GCC's default contracts where FMA is baseline, e.g. AArch64), so
#: scalar and vector code round alike.
CFLAGS: tuple[str, ...] = ("-O3", "-fPIC", "-shared", "-pthread", "-ffp-contract=off")
#: Extra flags of the vectorised C++: -fno-math-errno lets sqrt become one vector
#: instruction (errno is never read).
SIMD_CFLAGS: tuple[str, ...] = ("-x", "c++", "-fno-math-errno")

#: Largest generated C source compiled [bytes]. The simulators and sensitivities of the
#: package's models generate 30-110 kB (108 functions of a rig loop with discovery,
#: measured); a candidate of the one-loop study generated 82 MB, one per-sample function
#: of 3 million lines, whose compile ran over 30 CPU minutes and 3 GB before it was
#: stopped. Such an expression is no model to simulate (CasADi's virtual machine would
#: evaluate the same 3 million operations per sample): it is refused at once.
MAX_SOURCE_BYTES = 8_000_000

_CASADI_INT = ctypes.c_longlong  # the generated code's default ``casadi_int``
_lock = threading.Lock()  # guards _locks
_locks: dict[str, threading.Lock] = {}  # one per cache entry: different entries compile at once
_failed: set[str] = set()  # digests of sources that did not compile


def cache_dir() -> Path:
    """Directory of compiled simulators: ``$HHRA_PHYS_CACHE`` or ``~/.cache/hhra-phys``."""
    root = os.environ.get("HHRA_PHYS_CACHE")
    path = Path(root) if root else Path.home() / ".cache" / "hhra-phys"
    path.mkdir(parents=True, exist_ok=True)
    return path


def find_compiler() -> str | None:
    """The C compiler to use: ``$CC``, else ``cc``, ``gcc`` or ``clang`` on the PATH."""
    candidates = [os.environ.get("CC"), "cc", "gcc", "clang"]
    for cand in candidates:
        if cand and shutil.which(cand):
            return cand
    return None


class CompiledFunction:
    """A CasADi function compiled to a shared library and called through ctypes.

    Parameters
    ----------
    library : Path
        The shared library.
    name : str
        Name of the generated function.
    in_shapes, out_shapes : sequence of (rows, cols)
        Dense shapes of the inputs and outputs (column-major, as in CasADi).
    width : int
        SIMD lanes per element (1 for scalar code). With ``width > 1`` every
        element is ``width`` consecutive doubles, one per independent instance.
    """

    def __init__(
        self,
        library: Path,
        name: str,
        in_shapes: Sequence[tuple[int, int]],
        out_shapes: Sequence[tuple[int, int]],
        width: int = 1,
    ) -> None:
        self.library = library
        self.name = name
        self.in_shapes = list(in_shapes)
        self.out_shapes = list(out_shapes)
        self.width = int(width)
        self._lib = ctypes.CDLL(str(library))
        self._fn = getattr(self._lib, name)
        self._fn.restype = ctypes.c_int
        self._fn.argtypes = [
            ctypes.POINTER(ctypes.c_void_p),
            ctypes.POINTER(ctypes.c_void_p),
            ctypes.POINTER(_CASADI_INT),
            ctypes.POINTER(ctypes.c_double),
            ctypes.c_int,
        ]
        work = getattr(self._lib, name + "_work")
        sizes = [_CASADI_INT() for _ in range(4)]
        work(*[ctypes.byref(s) for s in sizes])
        self.sz_arg, self.sz_res, self.sz_iw, self.sz_w = (int(s.value) for s in sizes)
        incref = getattr(self._lib, name + "_incref", None)
        if incref is not None:
            incref()

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        """Evaluate on dense float64 arrays given in CasADi's column-major layout.

        Scalar code (``width == 1``): each argument must have ``rows*cols``
        elements; it is read in Fortran order, and outputs are returned with their
        (rows, cols) shape.

        Vector code (``width > 1``): an argument is either ``rows*cols``
        elements (shared by every lane, read in Fortran order) or an array of
        shape (rows*cols, width) whose column ``l`` is lane ``l``'s argument;
        outputs are returned with shape (rows*cols, width).

        Work arrays are allocated per call so concurrent calls from several
        threads are safe.
        """
        if len(args) != len(self.in_shapes):
            raise TypeError(f"{self.name} takes {len(self.in_shapes)} arguments, got {len(args)}")
        width = self.width
        keep = []
        arg = (ctypes.c_void_p * max(self.sz_arg, 1))()
        for i, (a, shape) in enumerate(zip(args, self.in_shapes, strict=True)):
            buf = np.asarray(a, dtype=np.float64)
            n_el = shape[0] * shape[1]
            if width > 1 and buf.shape == (n_el, width):
                buf = np.ascontiguousarray(buf)
            elif buf.size == n_el:
                buf = np.asfortranarray(buf.reshape(shape, order="F"))
                if width > 1:  # shared by every lane
                    buf = np.repeat(buf.ravel(order="F"), width)
            else:
                expected = f"{shape}" + (f" or ({n_el}, {width})" if width > 1 else "")
                raise ValueError(
                    f"{self.name}: input {i} has shape {buf.shape}, expected {expected}"
                )
            keep.append(buf)
            arg[i] = buf.ctypes.data
        if width > 1:
            outs = [np.empty((r * c, width)) for r, c in self.out_shapes]
        else:
            outs = [np.empty(shape, dtype=np.float64, order="F") for shape in self.out_shapes]
        res = (ctypes.c_void_p * max(self.sz_res, 1))()
        for i, o in enumerate(outs):
            res[i] = o.ctypes.data
        iw = np.empty(max(self.sz_iw, 1), dtype=np.int64)
        w = np.empty(max(self.sz_w, 1) * width, dtype=np.float64)
        flag = self._fn(
            arg, res,
            iw.ctypes.data_as(ctypes.POINTER(_CASADI_INT)),
            w.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
            0,
        )
        if flag:
            raise RuntimeError(f"compiled function {self.name} returned error flag {flag}")
        return outs


def _check_dense(fn: ca.Function) -> None:
    """Refuse sparse inputs or outputs: the compiled call passes dense arrays."""
    for i in range(fn.n_in()):
        if not fn.sparsity_in(i).is_dense():
            raise ValueError(
                f"compile_function needs dense inputs; input {i} of {fn.name()} is sparse"
            )
    for i in range(fn.n_out()):
        if not fn.sparsity_out(i).is_dense():
            raise ValueError(
                f"compile_function needs dense outputs; output {i} of {fn.name()} is sparse "
                "(wrap it in casadi.densify)"
            )


def _c_source(fn: ca.Function) -> bytes:
    """The C source CasADi generates for ``fn``."""
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False})
        cg.add(fn)
        # Write into the temporary directory by prefix: changing the working
        # directory would break other threads (and a deleted cwd breaks the process).
        path = Path(cg.generate(tmp + os.sep))
        return path.read_bytes()


def _build(source: bytes, compiler: str, flags: tuple[str, ...], name: str, target: Path,
           digest: str, quiet: bool, simd: SimdTarget | None) -> bool:
    """Compile ``source`` with ``compiler`` and ``flags`` into ``target``.

    Returns False (after a warning, or raises when not ``quiet``) if the compiler fails;
    the failure is remembered by ``digest`` so this process does not retry it.
    """
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        src = Path(tmp, f"{name}.c")
        src.write_bytes(source)
        out = Path(tmp, target.name)
        proc = subprocess.run(
            [compiler, *flags, str(src), "-o", str(out), "-lm"],
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            _failed.add(digest)  # do not retry in this process
            msg = f"compiling {name} with {compiler} failed:\n{proc.stderr[-2000:]}"
            if not quiet:
                raise RuntimeError(msg)
            fallback = ("scalar code" if simd is not None
                        else "CasADi's virtual machine")
            # stacklevel 4: the frame compile_function's own warnings name (3 there)
            warnings.warn(msg + f"\nusing {fallback} instead",
                          RuntimeWarning, stacklevel=4)
            return False
        os.replace(out, target)  # atomic: concurrent processes never see half a file
    return True


def compile_function(
    fn: ca.Function, quiet: bool = True, simd: SimdTarget | None = None
) -> CompiledFunction | None:
    """Compile ``fn`` to native code (cached on disk) or return ``None`` if impossible.

    Parameters
    ----------
    fn : casadi.Function
        A function with dense inputs and outputs.
    quiet : bool
        Only warn (once per failure) instead of raising when compilation fails.
    simd : SimdTarget, optional
        Compile vector code evaluating ``simd.width`` instances per call (see
        :mod:`hhra_phys.vectorize`). A model the vector type cannot express fails
        to compile; callers then use scalar code.
    """
    compiler = find_compiler() if simd is None else simd.compiler
    if compiler is None:
        warnings.warn(
            "no C compiler found (set CC or install gcc); using CasADi's virtual machine, "
            "which is several times slower",
            RuntimeWarning,
            stacklevel=3,
        )
        return None
    _check_dense(fn)
    name = fn.name()
    source = _c_source(fn)
    if len(source) > MAX_SOURCE_BYTES:
        raise ModelError(
            f"the generated code of {name} is {len(source) / 1e6:.0f} MB, more than the "
            f"{MAX_SOURCE_BYTES / 1e6:.0f} MB a simulator may have: its expression has grown "
            "beyond any model's (a loop's candidate with it fails its refit and is skipped); "
            "compiling it would take tens of minutes, and backend='casadi' would evaluate "
            "as many operations per sample")
    flags = CFLAGS
    if simd is not None:
        source = transform_source(source.decode()).encode()
        flags = CFLAGS + SIMD_CFLAGS + (f"-DHV_W={simd.width}",) + simd.flags
    digest = hashlib.sha256(source + " ".join((compiler,) + flags).encode()).hexdigest()[:20]
    target = cache_dir() / f"{name}_{digest}.so"
    if digest in _failed:
        return None
    with _lock:
        entry_lock = _locks.setdefault(digest, threading.Lock())
    with entry_lock:
        if not target.exists() and not _build(source, compiler, flags, name, target,
                                              digest, quiet, simd):
            return None
    shapes_in = [(fn.size1_in(i), fn.size2_in(i)) for i in range(fn.n_in())]
    shapes_out = [(fn.size1_out(i), fn.size2_out(i)) for i in range(fn.n_out())]
    return CompiledFunction(target, name, shapes_in, shapes_out,
                            1 if simd is None else simd.width)
