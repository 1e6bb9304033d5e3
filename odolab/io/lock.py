"""A folder held by one odolab run at a time: a second run into a folder in use is refused at once.

The lock is an exclusive, non-blocking ``fcntl.flock`` on the folder itself (a descriptor of the
directory), so nothing is written into the folder: no lock file for a manifest, a folder check or
a listing to mistake for a result, and none left behind. The operating system releases it when
the process ends, however it ends (a killed run never blocks the next); :meth:`FolderLock.release`,
leaving its ``with`` block or dropping the object releases it sooner.
"""

from __future__ import annotations

import errno
import fcntl
import gc
import os
import sys
import weakref
from pathlib import Path
from typing import Self

from odolab.core.errors import InputError

__all__ = ["FolderInUseError", "FolderLock", "holder_pid", "lock_folder"]

#: Where Linux lists the file locks held (``/proc/locks``): who holds a folder, for the message.
PROC_LOCKS = "/proc/locks"


class FolderInUseError(InputError):
    """A folder another running odolab process holds (:func:`lock_folder`); ``pid`` is its process
    id where the system tells it, else None. ``err.named("--out")`` words it after the option."""

    subject = "folder"

    def __init__(self, folder: str | os.PathLike, pid: int | None) -> None:
        self.folder, self.pid = Path(folder), pid
        who = f"another odolab run (pid {pid})" if pid is not None else "another odolab run"
        super().__init__(f"{self.folder} is in use by {who}; wait for it to finish or choose another folder")


def holder_pid(folder: str | os.PathLike, proc_locks: str = PROC_LOCKS) -> int | None:
    """The process id holding a ``flock`` on ``folder``, read from ``proc_locks`` (Linux); None
    where the system does not tell (another OS, another process namespace, nothing held)."""
    try:
        st = os.stat(folder)
        with open(proc_locks, encoding="ascii", errors="replace") as f:
            lines = f.read(1_000_000).splitlines()
    except OSError:
        return None
    wanted = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    for line in lines:
        fields = line.split()
        if len(fields) < 6 or fields[1] != "FLOCK":  # "N: -> FLOCK ..." lines are waiters, not holders
            continue
        try:
            major, minor, inode = fields[5].split(":")
            pid = int(fields[4])
            if (int(major, 16), int(minor, 16), int(inode)) == wanted and pid > 0:
                return pid
        except ValueError:
            continue
    return None


class FolderLock:
    """The exclusive hold of one run on ``folder`` (an existing folder): :meth:`acquire` takes it
    or raises :class:`FolderInUseError`; :meth:`release` (or the end of a ``with`` block, or the
    object's collection, or the process's end) gives it back."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self.held = False
        self._close: weakref.finalize | None = None

    def acquire(self) -> Self:
        """Take the folder, at once or not at all: :class:`FolderInUseError` naming the holder's pid
        when another process holds it. Where the file system has no locks (some network file
        systems) the run goes on unlocked, said in one line on stderr."""
        if self.held:
            return self
        fd = os.open(self.folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                if holder_pid(self.folder) != os.getpid():
                    raise
                # held by this process: perhaps by a finished run's hold that only a reference cycle
                # keeps (its frames in a traceback's cycle): collected, it lets go; a live one does not
                gc.collect()
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise FolderInUseError(self.folder, holder_pid(self.folder)) from None
        except OSError as exc:  # no locks here (ENOLCK, EOPNOTSUPP, EBADF on NFS): not a reason to stop
            os.close(fd)
            reason = errno.errorcode.get(exc.errno or 0, "") or exc.strerror or str(exc)
            print(
                f"odolab: note: cannot lock {self.folder} against other runs ({reason}); "
                "two runs into it at once would not be refused",
                file=sys.stderr,
            )
            return self
        self._close = weakref.finalize(self, os.close, fd)
        self.held = True
        return self

    def release(self) -> None:
        """Give the folder back (closing the descriptor releases the lock); again: nothing."""
        if self._close is not None:
            self._close()
            self._close = None
        self.held = False

    def __enter__(self) -> Self:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def lock_folder(folder: str | os.PathLike) -> FolderLock:
    """:class:`FolderLock` of ``folder``, acquired (:class:`FolderInUseError` when in use)."""
    return FolderLock(folder).acquire()
