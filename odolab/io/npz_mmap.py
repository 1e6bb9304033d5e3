"""Read one array stored in an *uncompressed* ``.npz`` file in place, without reading the rest.

``np.load(path, mmap_mode="r")`` ignores ``mmap_mode`` for ``.npz`` archives and reads a whole
member on access. A member written by ``np.savez`` (not ``savez_compressed``) is a plain ``.npy``
file stored byte for byte in the zip archive, so it can be read in place: find the member's local
header (zip format, APPNOTE 4.3.7), skip it, parse the ``.npy`` header (:mod:`numpy.lib.format`),
and read the data that follows. :func:`mmap_npz_member` maps it (slicing reads only the slice's
pages); :class:`NpzRows` reads whole rows with one ``pread`` each and no readahead, for data larger
than memory read in random order, where a map's page faults read megabytes around each row (the
kernel's read-around is the block device's readahead, 8 MB on some virtual disks).
"""

from __future__ import annotations

import os
import struct
import zipfile

import numpy as np

__all__ = ["NpzRows", "mmap_npz_member"]

_LOCAL_HEADER = struct.Struct("<4s22xHH")  # signature, 22 bytes we skip, name length, extra length
_LOCAL_SIGNATURE = b"PK\x03\x04"


def mmap_npz_member(path: str | os.PathLike, name: str) -> np.memmap:
    """Read-only map of array ``name`` (without ``.npy``) of the ``.npz`` file ``path``.

    Raises ``ValueError`` naming the file when the member is missing, compressed, or not an array.
    """
    offset, shape, fortran, dtype = _locate(path, name)
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C")


def _locate(path: str | os.PathLike, name: str) -> tuple[int, tuple[int, ...], bool, np.dtype]:
    """(byte offset of the data, shape, Fortran order, dtype) of array ``name`` of ``path``."""
    member = f"{name}.npy"
    with zipfile.ZipFile(path) as archive:
        try:
            info = archive.getinfo(member)
        except KeyError:
            raise ValueError(f"{path}: no array {name!r} in the archive") from None
    if info.compress_type != zipfile.ZIP_STORED:
        raise ValueError(f"{path}: array {name!r} is compressed; only np.savez (uncompressed) files can be mapped")
    with open(path, "rb") as f:
        f.seek(info.header_offset)
        signature, name_len, extra_len = _LOCAL_HEADER.unpack(f.read(_LOCAL_HEADER.size))
        if signature != _LOCAL_SIGNATURE:
            raise ValueError(f"{path}: damaged zip entry for {name!r}")
        f.seek(info.header_offset + _LOCAL_HEADER.size + name_len + extra_len)
        version = np.lib.format.read_magic(f)
        readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
        if version not in readers:
            raise ValueError(f"{path}: array {name!r} uses .npy format {version}; expected 1.0 or 2.0")
        shape, fortran, dtype = readers[version](f)
        if dtype.hasobject:
            raise ValueError(f"{path}: array {name!r} holds Python objects; refusing to map it")
        return f.tell(), shape, fortran, dtype


class NpzRows:
    """Rows (along axis 0) of array ``name`` of the uncompressed ``.npz`` file ``path``, read with one
    ``os.pread`` each from a file opened for random access (``POSIX_FADV_RANDOM``: no readahead), so a
    row costs its own bytes. :meth:`advise` starts reading rows that will be wanted soon
    (``POSIX_FADV_WILLNEED``), so the disk works while the caller computes. The file is opened on
    first use in each process (a pickled copy reopens it). ``ValueError`` as :func:`mmap_npz_member`."""

    def __init__(self, path: str | os.PathLike, name: str) -> None:
        self.path = os.fspath(path)
        self.offset, self.shape, fortran, self.dtype = _locate(path, name)
        if fortran and len(self.shape) > 1:
            raise ValueError(f"{path}: array {name!r} is stored in Fortran order; rows are not contiguous")
        self.row_shape = tuple(self.shape[1:])
        self.row_bytes = int(np.prod(self.row_shape, dtype=np.int64)) * self.dtype.itemsize
        self._fd: int | None = None

    def __len__(self) -> int:
        return int(self.shape[0])

    def _file(self) -> int:
        if self._fd is None:
            fd = os.open(self.path, os.O_RDONLY)
            if hasattr(os, "posix_fadvise"):
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_RANDOM)
            self._fd = fd
        return self._fd

    def _where(self, k: int) -> int:
        if not 0 <= k < self.shape[0]:
            raise IndexError(f"{self.path}: row {k} of {self.shape[0]}")
        return self.offset + k * self.row_bytes

    def read(self, k: int) -> np.ndarray:
        """Row ``k`` as a new array of shape ``shape[1:]``."""
        where, out = self._where(k), np.empty(self.row_shape, self.dtype)
        view = memoryview(out).cast("B")
        done = 0
        while done < self.row_bytes:  # pread may return fewer bytes than asked
            got = os.preadv(self._file(), [view[done:]], where + done)
            if got <= 0:
                raise ValueError(f"{self.path}: file ends inside row {k} (truncated?)")
            done += got
        return out

    def advise(self, rows: np.ndarray) -> None:
        """Ask the kernel to start reading ``rows`` now (no effect where the platform lacks it)."""
        if hasattr(os, "posix_fadvise"):
            fd = self._file()
            for k in np.unique(np.asarray(rows, np.int64)):
                os.posix_fadvise(fd, self._where(int(k)), self.row_bytes, os.POSIX_FADV_WILLNEED)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __del__(self) -> None:
        self.close()

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_fd": None}
