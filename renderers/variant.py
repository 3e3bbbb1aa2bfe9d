"""Choose the Mitsuba variant: CUDA if a GPU works, else LLVM (libLLVM >= 17), else scalar.

drjit 1.5 emits ``llvm.minimum``/``llvm.maximum``; libLLVM 15 and 16 cannot compile them and abort
the whole process (uncatchable). So the LLVM backend is only used with a libLLVM of version 17 or
newer, which is pointed to through ``DRJIT_LIBLLVM_PATH`` before drjit is imported.

``python -m renderers.variant`` prints what would be chosen; ``--has-llvm`` exits 0 only if a
usable libLLVM exists (the Makefile uses it to decide whether to install ``libllvm19``).
"""

from __future__ import annotations

import glob
import os
import re
import sys
import warnings
from pathlib import Path

MIN_LLVM_MAJOR = 17
VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
FAST_PATH_HINT = (
    "for the ~8x faster llvm_ad_rgb variant install libLLVM 17 or newer "
    "(Debian/Ubuntu: `sudo apt-get install libllvm19`; `make setup` does it when run as root) "
    "or point DRJIT_LIBLLVM_PATH at such a libLLVM.so"
)
_LIB_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
)
_chosen: str | None = None


def llvm_major(path: str) -> int | None:
    """LLVM major version read from a library path (libLLVM-19.so, libLLVM.so.19.1, llvm-19/)."""
    for pattern in (
        r"libLLVM-(\d+)",
        r"libLLVM\.so\.(\d+)",
        r"llvm-(\d+)/",
        r"libLLVM\.(\d+)\.dylib",
    ):
        m = re.search(pattern, path)
        if m:
            return int(m.group(1))
    return None


def find_libllvm(min_major: int = MIN_LLVM_MAJOR) -> tuple[str, int] | None:
    """The newest libLLVM of at least ``min_major`` on this machine, as (path, major)."""
    found = []
    for pattern in _LIB_GLOBS:
        for path in glob.glob(pattern):
            major = llvm_major(path)
            if major is not None and major >= min_major and Path(path).exists():
                found.append((major, path))
    if not found:
        return None
    major, path = max(found)
    return path, major


def gpu_present() -> bool:
    """Whether an NVIDIA device node exists (cheap: no CUDA call)."""
    return Path("/dev/nvidiactl").exists() or Path("/dev/nvidia0").exists()


def select_variant(requested: str | None = None) -> str:
    """Set and return the Mitsuba variant; ``requested`` overrides the automatic choice.

    Must run before drjit is first imported (it sets ``DRJIT_LIBLLVM_PATH``). Idempotent.
    """
    global _chosen
    if requested is not None and requested not in VARIANTS:
        raise ValueError(f"variant={requested!r}: choose one of {', '.join(VARIANTS)}")
    if _chosen is not None and requested in (None, _chosen):
        return _chosen
    user_path = os.environ.get("DRJIT_LIBLLVM_PATH")
    llvm = (user_path, llvm_major(user_path) or MIN_LLVM_MAJOR) if user_path else find_libllvm()
    if llvm is not None and "drjit" not in sys.modules:
        os.environ["DRJIT_LIBLLVM_PATH"] = llvm[0]
    import mitsuba as mi

    candidates = [requested] if requested else []
    if not candidates:
        if gpu_present():
            candidates.append("cuda_ad_rgb")
        if llvm is not None:
            candidates.append("llvm_ad_rgb")
        candidates.append("scalar_rgb")
    if requested == "llvm_ad_rgb" and llvm is None:
        raise ValueError(f"variant=llvm_ad_rgb needs libLLVM >= {MIN_LLVM_MAJOR}: {FAST_PATH_HINT}")
    errors = []
    for name in candidates:
        try:
            mi.set_variant(name)
        except (ImportError, RuntimeError, AttributeError) as exc:
            errors.append(f"{name}: {exc}")
            continue
        _chosen = name
        if name == "scalar_rgb" and requested is None:
            warnings.warn(
                f"Mitsuba runs in scalar_rgb, the slow path: {FAST_PATH_HINT}.", stacklevel=2
            )
        return name
    raise RuntimeError("no Mitsuba variant could be set: " + "; ".join(errors))


def jit_variant_active() -> bool:
    """Whether the Mitsuba variant set in this process is a JIT one (``llvm_ad_rgb`` or
    ``cuda_ad_rgb``): vectorized, millions of rays per call."""
    import mitsuba as mi

    return mi.variant() is not None and not mi.variant().startswith("scalar")


def init_worker(variant: str | None, threads: int | None = None) -> str:
    """Set the Mitsuba variant (and Dr.Jit's thread count) in this process; return the variant.

    Once per process that renders: each pool worker runs it before its first task.
    """
    chosen = select_variant(variant)
    if threads:
        set_threads(threads)
    return chosen


def set_threads(threads: int) -> None:
    """Dr.Jit's thread count in this process, changed only when it differs (between frames)."""
    import drjit as dr

    if dr.thread_count() != threads:
        dr.set_thread_count(threads)


def _main() -> int:
    llvm = find_libllvm()
    if "--has-llvm" in sys.argv:
        return 0 if llvm else 1
    print(f"libLLVM >= {MIN_LLVM_MAJOR}: {llvm[0] + ' (' + str(llvm[1]) + ')' if llvm else 'none'}")
    print(f"variant: {select_variant()}")
    return 0


if __name__ == "__main__":
    sys.exit(_main())
