"""Locating a working `libLLVM` for Dr.Jit and importing Mitsuba with a suitable variant.

Dr.Jit's CPU backend compiles kernels with a shared `libLLVM` that it loads at import
time. Old system versions (Debian's LLVM 14/15) crash it with obscure instruction
selection errors, so the library is chosen here, before `drjit` is first imported:
an explicit `DRJIT_LIBLLVM_PATH`, else a system libLLVM of major version >= 16, else the
one shipped by the `karellen-llvm-core` wheel (installed by the `mitsuba` extra).
"""

from __future__ import annotations

import importlib.metadata
import os
import re
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import ModuleType

ENV_VAR = "DRJIT_LIBLLVM_PATH"
MIN_LLVM_MAJOR = 16
SUPPORTED_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")

# Directories searched for a system libLLVM (`llvm-*/lib` subfolders are searched too).
SYSTEM_LIB_DIRS: tuple[str, ...] = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
    "/opt/homebrew/opt/llvm/lib",
    "/usr/local/opt/llvm/lib",
)
KARELLEN_DISTRIBUTION = "karellen-llvm-core"

_INSTALL_ADVICE = (
    "Install one with `pip install 'restore-mcmc[mitsuba]'` (which brings the "
    "`karellen-llvm-core` wheel) or a system libLLVM of major version >= "
    f"{MIN_LLVM_MAJOR} (e.g. Debian/Ubuntu `apt install libllvm19`), then, if it is not "
    f"found automatically, point {ENV_VAR} at the library file, e.g. "
    f"`export {ENV_VAR}=/usr/lib/llvm-19/lib/libLLVM.so.1`."
)
_VERSION_PATTERNS = (
    re.compile(r"^libLLVM-(\d+)(?:\.\d+)*\.(?:so|dylib)(?:\.\d+)*$"),
    re.compile(r"^libLLVM\.so\.(\d+)(?:\.\d+)*$"),
    re.compile(r"^libLLVM\.(\d+)(?:\.\d+)*\.dylib$"),
)


class LLVMNotFoundError(RuntimeError):
    """No libLLVM usable by Dr.Jit's CPU backend (major version >= 16) was found."""


def find_libllvm() -> Path:
    """The libLLVM that Dr.Jit's CPU backend should load.

    Order: an existing file named by `DRJIT_LIBLLVM_PATH`; the newest system libLLVM of
    major version >= 16 in `SYSTEM_LIB_DIRS`; the library of the `karellen-llvm-core`
    wheel.

    Raises:
        LLVMNotFoundError: when none is found; the message says what to install.
    """
    notes = []
    explicit = os.environ.get(ENV_VAR)
    if explicit:
        path = Path(explicit).expanduser()
        if path.is_file():
            return path
        notes.append(f"{ENV_VAR}={explicit!r} does not name an existing file.")
    system = _best_system_libllvm(SYSTEM_LIB_DIRS)
    if system is not None:
        return system
    for path in _karellen_libraries():
        if path.is_file():
            return path
    notes.append(
        f"No system libLLVM of major version >= {MIN_LLVM_MAJOR} was found in "
        f"{', '.join(SYSTEM_LIB_DIRS)}, and the `{KARELLEN_DISTRIBUTION}` wheel is not installed."
    )
    raise LLVMNotFoundError(
        "Dr.Jit's CPU backend needs a shared libLLVM of major version >= "
        f"{MIN_LLVM_MAJOR} (older ones crash it). " + " ".join(notes) + " " + _INSTALL_ADVICE
    )


def llvm_major_version(path: Path) -> int | None:
    """The LLVM major version encoded in a library file name, or `None` if it has none."""
    for pattern in _VERSION_PATTERNS:
        match = pattern.match(path.name)
        if match:
            return int(match.group(1))
    return None


def load_mitsuba(variant: str | None = None) -> ModuleType:
    """Import Mitsuba with a working Dr.Jit backend and set an AD RGB variant.

    Sets `DRJIT_LIBLLVM_PATH` (from `find_libllvm`) before `drjit` is first imported;
    if `drjit` is already imported this step is skipped. With `variant=None` an already
    selected supported variant is kept, else `cuda_ad_rgb` is used when Mitsuba was built
    with it and a CUDA device works, and `llvm_ad_rgb` otherwise (`preferred_variant`).

    Arguments:
        variant: `None`, `"llvm_ad_rgb"` or `"cuda_ad_rgb"`.

    Returns:
        The `mitsuba` module, with the variant set.

    Raises:
        ImportError: if Mitsuba is not installed.
        LLVMNotFoundError: if the CPU variant is needed and no usable libLLVM exists.
        ValueError: for an unsupported variant name.
    """
    if variant is not None and variant not in SUPPORTED_VARIANTS:
        raise ValueError(
            f"unsupported Mitsuba variant {variant!r}: the primary-sample-space tracer needs "
            f"an RGB variant with automatic differentiation, one of {SUPPORTED_VARIANTS}"
        )
    llvm_error: LLVMNotFoundError | None = None
    if "drjit" not in sys.modules:
        try:
            os.environ[ENV_VAR] = str(find_libllvm())
        except LLVMNotFoundError as err:
            llvm_error = err
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as err:
        raise ImportError(
            "Mitsuba 3 is not installed; install the `mitsuba` extra: "
            "`pip install 'restore-mcmc[mitsuba]'`"
        ) from err

    if variant is None:
        current = mi.variant()
        if current in SUPPORTED_VARIANTS:
            return mi
        variant = preferred_variant(mi, dr)
    if variant.startswith("llvm"):
        _check_llvm_backend(dr, llvm_error)
    if variant.startswith("cuda") and variant not in mi.variants():
        raise ValueError(f"variant {variant!r} was requested but this Mitsuba build has only {mi.variants()}")
    if variant.startswith("cuda") and not _has_backend(dr, "CUDA"):
        raise ValueError("variant 'cuda_ad_rgb' was requested but no working CUDA device was found")
    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


def preferred_variant(mi: ModuleType, dr: ModuleType) -> str:
    """`"cuda_ad_rgb"` when this Mitsuba build has it and Dr.Jit can use a CUDA device, else `"llvm_ad_rgb"`."""
    if "cuda_ad_rgb" in mi.variants() and _has_backend(dr, "CUDA"):
        return "cuda_ad_rgb"
    return "llvm_ad_rgb"


def _check_llvm_backend(dr: ModuleType, llvm_error: LLVMNotFoundError | None) -> None:
    """Raise `LLVMNotFoundError` unless Dr.Jit's CPU backend loaded a libLLVM >= 16."""
    if not _has_backend(dr, "LLVM"):
        if llvm_error is not None:
            raise llvm_error
        raise LLVMNotFoundError(
            f"Dr.Jit's CPU backend could not load a libLLVM ({ENV_VAR}="
            f"{os.environ.get(ENV_VAR)!r}); it needs major version >= {MIN_LLVM_MAJOR}. " + _INSTALL_ADVICE
        )
    try:
        major = int(dr.detail.llvm_version()[0])
    except Exception:  # no version query in this Dr.Jit: trust the backend
        return
    if major < MIN_LLVM_MAJOR:
        raise LLVMNotFoundError(
            f"Dr.Jit's CPU backend loaded libLLVM {major}, which crashes it (major version >= "
            f"{MIN_LLVM_MAJOR} is needed). Dr.Jit picks its libLLVM when it is first imported "
            f"(here {ENV_VAR}={os.environ.get(ENV_VAR)!r}): call `targets.mitsuba.load_mitsuba()` "
            f"before anything imports drjit or mitsuba, or set {ENV_VAR} to a newer library. "
            + _INSTALL_ADVICE
        )


def _has_backend(dr: ModuleType, name: str) -> bool:
    try:
        return bool(dr.has_backend(getattr(dr.JitBackend, name)))
    except Exception:  # a broken driver or library: treat as absent
        return False


def _best_system_libllvm(dirs: Iterable[str]) -> Path | None:
    """The system libLLVM with the highest major version >= `MIN_LLVM_MAJOR`, if any."""
    best: tuple[int, Path] | None = None
    for path in _candidate_files(dirs):
        major = llvm_major_version(path)
        if major is None or major < MIN_LLVM_MAJOR:
            continue
        if best is None or major > best[0]:
            best = (major, path)
    return None if best is None else best[1]


def _candidate_files(dirs: Iterable[str]) -> Iterator[Path]:
    for name in dirs:
        root = Path(name)
        if not root.is_dir():
            continue
        folders = [root] + sorted(p / "lib" for p in root.glob("llvm-*") if (p / "lib").is_dir())
        for folder in folders:
            for path in sorted(folder.glob("libLLVM*")):
                if path.is_file():
                    yield path


def _karellen_libraries() -> list[Path]:
    """libLLVM files installed by the `karellen-llvm-core` wheel (next to `sys.prefix/lib`)."""
    try:
        dist = importlib.metadata.distribution(KARELLEN_DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        return []
    files = [f for f in (dist.files or []) if f.name.startswith("libLLVM")]
    paths = [Path(str(dist.locate_file(f))).resolve() for f in files]
    # Prefer the versioned file (the others are symbolic links to it).
    paths.sort(key=lambda p: (llvm_major_version(p) is None, str(p)))
    return paths
