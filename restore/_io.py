"""Atomic file writes: a reader (or a run killed mid-write) never sees a half-written file."""

from __future__ import annotations

import csv
import glob
import io
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path


def matplotlib_for(what: str, backend: str | None = "Agg"):
    """The `matplotlib` module (with `backend`, when given), or an ImportError that says what to install.

    matplotlib is an optional extra (`plot`; `compare` and `mitsuba` bring it too): figures
    and PNG images need it, nothing else does.
    """
    try:
        import matplotlib
    except ImportError as err:
        raise ImportError(f"{what} needs matplotlib: pip install 'restore-mcmc[plot]'") from err
    if backend is not None:
        matplotlib.use(backend)
    return matplotlib


def _file_mode(path: Path) -> int:
    """The permission bits a plain `open(path, "w")` would leave: the old file's, else 0o666 less the umask."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def write_text(path: str | os.PathLike, text: str, newline: str | None = None) -> Path:
    """Write `text` to `path` atomically (UTF-8)."""

    def write(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8", newline=newline) as handle:
            handle.write(text)

    return atomic_write(path, write)


def write_csv(path: str | os.PathLike, rows: Sequence[Mapping], columns: Sequence[str] | None = None) -> Path:
    """Write `rows` (mappings) to `path` as CSV atomically, with a header of `columns` (default:
    the first row's keys); keys of a row outside `columns` are left out."""
    columns = list(rows[0]) if columns is None else list(columns)
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=columns, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    return write_text(path, text.getvalue(), newline="")


def save_figure(fig, path: str | os.PathLike, **kwargs) -> Path:
    """`fig.savefig` to `path` atomically, in the format named by its suffix (e.g. `.png`)."""
    path = Path(path)
    fmt = kwargs.pop("format", path.suffix.lstrip(".").lower() or "png")
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format=fmt, **kwargs))


def save_and_close(fig, path: str | os.PathLike, **kwargs) -> Path:
    """`save_figure`, then close `fig` (also when saving fails), so that a program making
    many figures does not keep them all open."""
    import matplotlib.pyplot as plt

    try:
        return save_figure(fig, path, **kwargs)
    finally:
        plt.close(fig)


def atomic_write(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Call `write(tmp_path)` on a temporary file beside `path`, flush it to disk, then rename it to `path`.

    The rename is atomic on POSIX file systems, so `path` holds either its old content or
    the new one, never a mixture. If `write` raises (or the process is interrupted), the
    temporary file is removed and `path` is left as it was; a temporary file left by a
    process killed outright (SIGKILL) during an earlier write is removed by the next
    write. The new file gets the mode of
    the file it replaces, or the usual `0o666` less the umask for a new file (not the
    private `0o600` of a temporary file).

    `write` must write to exactly the path it is given: NumPy's `np.save`/`np.savez` append
    `.npy`/`.npz` to a name that does not end in it, so give them an open file handle.

    Raises:
        FileNotFoundError: if the folder of `path` does not exist.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"cannot write {path}: folder {folder} does not exist")
    for stale in folder.glob(f".{glob.escape(path.name)}.*.tmp{glob.escape(path.suffix)}"):
        stale.unlink(missing_ok=True)  # left by a process killed outright while it wrote `path`
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=folder)
    os.close(fd)
    try:
        write(Path(tmp))
        with open(tmp, "rb+") as handle:  # the data reach the disk before the rename makes them visible
            os.fsync(handle.fileno())
        os.chmod(tmp, _file_mode(path))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
