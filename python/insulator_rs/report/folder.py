"""Report folders that never describe one run with another run's files.

A run writes into a folder of its own:

* ``--out`` names a folder that does not exist or is empty: the run writes straight into
  it, and its ``summary.json`` says ``"running"`` before any other file is there, so a run
  killed at any point leaves a folder that says it did not finish.
* ``--out`` names a folder that holds files: refused, unless ``--overwrite`` is given and
  the folder holds an insulator_rs report (a ``summary.json``; an arbitrary folder is never
  replaced). With ``--overwrite`` the new run writes into a hidden temporary sibling
  (``.NAME.new-XXXX``) and the old report stays complete and untouched in ``--out`` until
  the run ends, when the two folders are exchanged in one step (Linux ``renameat2``
  ``RENAME_EXCHANGE``) and the old one is deleted. Killed before that, ``--out`` is the
  old complete report and the sibling holds the new run's partial report ("running");
  killed after, ``--out`` is the new report.

Where the exchange is not available (not Linux, or a filesystem without it) the old folder
is renamed to ``.NAME.old-XXXX`` and the new one renamed in: two renames, and a kill between
them leaves ``--out`` missing with both reports beside it, each complete and each named by
its own summary.
"""

from __future__ import annotations

import argparse
import ctypes
import errno
import os
import shutil
import sys
import tempfile
from pathlib import Path

# Linux renameat2(2): both paths relative to the working directory, swap them atomically.
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2
# A folder holding this file is an insulator_rs report (what --overwrite may replace).
SUMMARY_NAME = "summary.json"


def parse_out_folder(text: str) -> Path:
    """argparse ``type`` of ``--out``: a folder path; an empty string is refused (it would be
    the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a report folder, got an empty string")
    return Path(text)


def check_out_folder(out: Path, *, overwrite: bool) -> None:
    """Refuse ``out`` before anything flies: ValueError naming ``--out`` when it is not a folder,
    holds files (without ``overwrite``), or holds something other than a report (with it)."""
    if str(out).strip() == "":
        raise ValueError("--out: must name a report folder, got an empty string")
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise ValueError(f"--out: {out} exists and is not a folder")
        if any(out.iterdir()):
            if not overwrite:
                raise ValueError(f"--out: {out} already holds files; name a new folder, "
                                 f"or add --overwrite to replace the report in it")
            if not (out / SUMMARY_NAME).is_file():
                raise ValueError(f"--out: {out} holds files but no insulator_rs report ({SUMMARY_NAME}); "
                                 f"--overwrite only replaces a report folder")
            if out.is_symlink():
                raise ValueError(f"--out: {out} is a symbolic link; --overwrite replaces real folders only")
            here = Path.cwd().resolve()
            target = out.resolve()
            if target == here or target in here.parents:
                raise ValueError(f"--out: {out} is the current folder or holds it; refusing to replace it")


class ReportFolder:
    """The folder one run writes (``path``) and where it ends up (``final``).

    Opening checks ``final`` as :func:`check_out_folder` does; :meth:`commit` puts a staged
    report in place (nothing to do when the run writes straight into ``final``)."""

    def __init__(self, final: Path, *, overwrite: bool = False) -> None:
        self.final = Path(final)
        check_out_folder(self.final, overwrite=overwrite)
        self.staged = self.final.is_dir() and any(self.final.iterdir())
        if self.staged:
            self.path = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.new-", dir=self.final.parent))
            os.chmod(self.path, self.final.stat().st_mode & 0o7777)  # mkdtemp's 0700 would replace it
        else:
            self.final.mkdir(parents=True, exist_ok=True)
            self.path = self.final
        self.committed = not self.staged

    def leftovers(self) -> list[Path]:
        """Hidden siblings that earlier runs left when killed: ``.NAME.new-*`` (a replacing run's
        partial report, its summary says ``running``) and ``.NAME.old-*`` (a replaced report the
        two-rename fallback had not yet deleted). Kept for the user to look at, never deleted here."""
        return sorted(p for p in self.final.parent.glob(f".{self.final.name}.*-*")
                      if p.is_dir() and p != self.path and p.name.split(".")[-1].startswith(("new-", "old-")))

    def commit(self) -> None:
        """Put the staged report in ``final`` in one step and delete the old one (idempotent)."""
        if self.committed:
            return
        _fsync_dir(self.path)
        if _exchange(self.path, self.final):
            old = self.path  # after the exchange the staging name holds the old report
        else:
            old = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.old-", dir=self.final.parent))
            os.rename(self.final, old / "report")
            os.rename(self.path, self.final)
        _fsync_dir(self.final.parent)
        self.committed = True
        self.path = self.final
        shutil.rmtree(old, ignore_errors=True)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths atomically (Linux renameat2 RENAME_EXCHANGE); False where the
    system or the filesystem cannot, so the caller falls back to two renames."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):  # a libc without renameat2 (glibc < 2.28, musl < 1.2.?)
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    renameat2.restype = ctypes.c_int
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, f"could not exchange {a} and {b}: {os.strerror(err)}")


def _fsync_dir(folder: Path) -> None:
    """Flush a folder's entries (the renames in it) to disk; a no-op where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_atomic(path: Path, data: str | bytes, *, durable: bool = False) -> Path:
    """Write ``path`` through a temp file and a rename, so a kill never leaves half a file;
    ``durable`` also flushes it to disk first (survives a power cut, costs a few ms)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)
        if durable:
            f.flush()
            os.fsync(f.fileno())
    os.replace(tmp, path)
    return path
