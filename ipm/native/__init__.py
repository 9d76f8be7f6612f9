"""C kernels shipped as source files in this folder, built on first use and bound by their header.

A kernel ``NAME`` is ``NAME.c`` (with whatever ``.inc`` files it includes from here) and ``NAME.h``, which
declares the functions Python calls, once: ``NAME.c`` includes it, so the compiler checks the definitions
against it, and :func:`load` hands the same declarations to cffi (``FFI.cdef``; lines starting with ``#``
are for the compiler only) to bind the built library (ABI mode, ``FFI.dlopen``). Today two kernels:
``soft`` (the soft silhouette, :mod:`ipm.render.soft`, backend "native") and ``deferred`` (the deferred
renderer's z-buffer, barycentrics, interpolation and antialiasing, :mod:`ipm.render.deferred_native`).

Building: the C compiler ``$CC`` (default ``cc``) with :data:`FLAGS` (the first set that compiles), about a
second, once per source, compiler, flags and CPU; the library is cached under ``$IPM_CACHE_DIR`` (default
``~/.cache/ipm``) and written atomically, so concurrent processes may build it at once. Without a compiler
(or cffi) :func:`load` returns None and callers fall back to their pure-torch path.
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent

# Compile flags that give the same bits on every CPU (issue #28): IEEE arithmetic as written, with no fused
# multiply-adds the compiler picks (-ffp-contract=off) and no reassociation (no -ffast-math: with it the vector
# width, which -march=native sets per CPU, decided the order of sums); kernels compute exp themselves where
# they vectorize it (soft_kernel.inc: expneg), the same operations everywhere. -march=native then only chooses
# how fast: built for AVX-512 and for AVX2 (-march=x86-64-v3) the soft kernel gave the same image and gradient
# bit for bit, at 4.4 and 6.5 ms for the 6k-face dishes mug at 128^2 forward + backward, one thread, where
# -ffast-math and -march=native took 3.1 ms (AMD EPYC, 2026-11-27, best of 15;
# tests/test_render_soft_native.py checks the flags and the bits). The second set is for compilers without
# -march=native.
IEEE = ["-fno-math-errno", "-fno-trapping-math", "-ffp-contract=off", "-fopenmp"]
FLAGS: tuple[tuple[list[str], list[str]], ...] = ((["-O3", "-march=native", *IEEE], ["-fopenmp", "-lm"]),
                                                  (["-O3", *IEEE], ["-fopenmp", "-lm"]))


@dataclass(frozen=True)
class Kernel:
    """A built kernel: ``lib`` (its functions, as declared in its header) and ``ffi`` (for pointers:
    :meth:`ptr`)."""

    ffi: Any
    lib: Any
    path: Path

    def ptr(self, address: int):
        """A ``void *`` for a buffer's address (a tensor's ``data_ptr()``): cffi passes it to any pointer
        parameter."""
        return self.ffi.cast("void *", address)


_LOCK = threading.Lock()
_LOADED: dict[str, Kernel | None] = {}


def load(name: str) -> Kernel | None:
    """The kernel ``name`` (``NAME.c``, ``NAME.h`` here), built on first use; None where it cannot be built
    (no C compiler, no cffi; logged once at info level)."""
    with _LOCK:
        if name not in _LOADED:
            try:
                _LOADED[name] = _build(name)
            except (OSError, RuntimeError, ImportError) as e:
                log.info("native kernel %s: unavailable (%s); using the pure-torch path", name, e)
                _LOADED[name] = None
        return _LOADED[name]


def forget(name: str | None = None) -> None:
    """Drop the loaded kernel(s), so that the next :func:`load` builds or loads again (tests change
    :data:`FLAGS` or the cache folder)."""
    with _LOCK:
        if name is None:
            _LOADED.clear()
        else:
            _LOADED.pop(name, None)


def declarations(name: str) -> str:
    """The C declarations of kernel ``name``'s header without its preprocessor lines (what cffi reads)."""
    text = (HERE / f"{name}.h").read_text()
    return "\n".join(ln for ln in text.splitlines() if not ln.lstrip().startswith("#"))


def _sources(name: str) -> str:
    """Every file the build of ``name`` reads (its .c, .h and the folder's .inc), for the cache key."""
    files = [HERE / f"{name}.c", HERE / f"{name}.h", *sorted(HERE.glob("*.inc"))]
    return "\0".join(f"{f.name}\0{f.read_text()}" for f in files)


def _cpu_flags() -> str:
    try:
        return next((ln for ln in Path("/proc/cpuinfo").read_text().splitlines() if ln.startswith("flags")), "")
    except OSError:
        return ""


def _build(name: str) -> Kernel:
    import cffi

    cc = os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        raise RuntimeError(f"no C compiler {cc!r}")
    key = hashlib.sha256("\0".join([_sources(name), cc, repr(FLAGS), _cpu_flags(), platform.machine()]).encode())
    cache = Path(os.environ.get("IPM_CACHE_DIR") or Path.home() / ".cache" / "ipm")
    lib = cache / f"{name}_native_{key.hexdigest()[:16]}.so"
    if not lib.is_file():
        cache.mkdir(parents=True, exist_ok=True)
        errors = []
        with tempfile.TemporaryDirectory(dir=cache) as tmp:
            obj, so = Path(tmp) / f"{name}.o", Path(tmp) / f"{name}.so"
            for cflags, libs in FLAGS:
                r = subprocess.run([cc, *cflags, "-fPIC", "-I", str(HERE), "-c", str(HERE / f"{name}.c"), "-o",
                                    str(obj)], capture_output=True, text=True)
                if r.returncode == 0:
                    r = subprocess.run([cc, "-shared", str(obj), "-o", str(so), *libs], capture_output=True,
                                       text=True)
                if r.returncode == 0:
                    os.replace(so, lib)  # atomic: concurrent builders write the same file
                    break
                errors.append(r.stderr.strip().splitlines()[-1:] or ["?"])
            else:
                raise RuntimeError(f"{cc} failed: {errors}")
        log.info("native kernel %s: built %s", name, lib)
    ffi = cffi.FFI()
    ffi.cdef(declarations(name))
    return Kernel(ffi, ffi.dlopen(str(lib)), lib)
