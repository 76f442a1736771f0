"""How many threads the numeric libraries use: one, set in one place.

Every process that computes what a robot is told passes through :func:`pin_threads`: the
``teachrepeat`` command (``serve``, ``replay``, every benchmark, and the worker processes they
spawn), and the test suite (``tests/conftest.py``). With one thread, a product of float32
matrices sums in the same order in every process on a machine, so a recording made by the
server replays to the same numbers in another process. Across CPUs the order may still differ
(OpenBLAS and NumPy pick their kernels by CPU): ``teachrepeat replay`` compares within a
tolerance for that (:class:`server.recording.replay.Tolerance`).

One thread is also the faster choice for a server: it runs many small products, and OpenBLAS's
worker threads busy-wait on the cores the request threads need (``bench load``, 10 robots: p99
3.4 s -> 21 ms); OpenCV's operations on a 320x240 frame are too small to share (a frame's
features: 3.0 ms of CPU with two threads, 2.7 ms with one; docs/reliability.md, "2026-11-28").

Importing this module loads nothing heavy; :func:`pin_environment` must run before NumPy is
first imported to act through the environment, and :func:`pin_threads` acts on libraries
already loaded too.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys

VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")
"""The environment variables the numeric libraries read their thread count from."""


def pin_environment() -> None:
    """One thread for every library that has not started yet, in this process and in the
    processes it starts (a variable already set is left as it is)."""
    for var in VARIABLES:
        os.environ.setdefault(var, "1")


def pin_threads() -> str:
    """One thread for BLAS and OpenCV, loaded or not; what was done, for a benchmark's JSON."""
    pin_environment()
    done = [_limit_openblas(1)]
    if "cv2" in sys.modules or _importable("cv2"):
        import cv2

        cv2.setNumThreads(1)
        done.append("cv2.setNumThreads(1)")
    return ", ".join(done)


def _importable(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None


def openblas_core() -> str | None:
    """The name of the OpenBLAS kernel NumPy runs on this CPU (``"SkylakeX"``, ``"Haswell"``;
    ``OPENBLAS_CORETYPE`` overrides it), or ``None`` when it cannot be told."""
    for lib in _openblas_libraries():
        for name in ("scipy_openblas_get_corename64_", "openblas_get_corename"):
            if hasattr(lib, name):
                function = getattr(lib, name)
                function.restype = ctypes.c_char_p
                core = function()
                return core.decode() if core else None
    return None


def _openblas_libraries() -> list[ctypes.CDLL]:
    """The OpenBLAS libraries NumPy and SciPy bundle (loading them if need be)."""
    import numpy as np

    site = os.path.dirname(os.path.dirname(np.__file__))
    out = []
    for folder in ("numpy.libs", "scipy.libs", "scipy_openblas64", "scipy_openblas32"):
        pattern = os.path.join(site, folder, "**", "*openblas*.so*")
        for path in sorted(glob.glob(pattern, recursive=True)):
            try:
                out.append(ctypes.CDLL(path))
            except OSError:
                continue
    return out


def _limit_openblas(n: int) -> str:
    """Set the OpenBLAS that NumPy and SciPy bundle to ``n`` threads, also when they were
    loaded before the environment could act (best effort); what was done."""
    if "numpy" not in sys.modules:
        return "OPENBLAS_NUM_THREADS=1 (NumPy not loaded yet)"
    done: list[str] = []
    for lib in _openblas_libraries():
        for name in ("scipy_openblas_set_num_threads64_", "openblas_set_num_threads"):
            if hasattr(lib, name):
                getattr(lib, name)(ctypes.c_int(n))
                done.append(f"{name}({n})")
                break
    return ", ".join(sorted(set(done))) or "environment variables only"
