"""Memory-map one array stored in an *uncompressed* ``.npz`` file, without reading the rest.

``np.load(path, mmap_mode="r")`` ignores ``mmap_mode`` for ``.npz`` archives and reads a whole
member on access. A member written by ``np.savez`` (not ``savez_compressed``) is a plain ``.npy``
file stored byte for byte in the zip archive, so it can be mapped in place: find the member's local
header (zip format, APPNOTE 4.3.7), skip it, parse the ``.npy`` header (:mod:`numpy.lib.format`),
and map the data that follows. Slicing the map then reads only the pages of the slice.
"""

from __future__ import annotations

import os
import struct
import zipfile

import numpy as np

__all__ = ["mmap_npz_member"]

_LOCAL_HEADER = struct.Struct("<4s22xHH")  # signature, 22 bytes we skip, name length, extra length
_LOCAL_SIGNATURE = b"PK\x03\x04"


def mmap_npz_member(path: str | os.PathLike, name: str) -> np.memmap:
    """Read-only map of array ``name`` (without ``.npy``) of the ``.npz`` file ``path``.

    Raises ``ValueError`` naming the file when the member is missing, compressed, or not an array.
    """
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
        offset = f.tell()
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C")
