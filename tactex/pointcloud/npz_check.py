"""An .npz cloud's arrays read with their sizes and types checked before numpy allocates them.

``np.load`` reads a member's header (shape, dtype) and allocates shape × itemsize before it reads
the member's data: a header edited to a huge shape asks for gigabytes from a file of a few hundred
bytes. Each member's header is read here first; the bytes it announces must be the bytes the
archive says the member holds, and those no more than deflate can make of the bytes stored for it
(:data:`DEFLATE_MAX_RATIO`). Only numbers are read (no pickle, no text, no records), and the zip
features numpy does not read (encryption, other compressions, damaged streams) are refused in one
sentence naming the file.
"""

from __future__ import annotations

import contextlib
import math
import struct
import warnings
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from tokenize import TokenError

import numpy as np

from tactex.errors import CloudError

__all__ = ["DEFLATE_MAX_RATIO", "HEADER_ERRORS", "NPZ_ARRAYS", "NUMERIC_KINDS", "kind_words", "npy_header",
           "quiet_numpy_header", "read_npz_arrays"]

#: The arrays a cloud is read from; other members of the archive are not read.
NPZ_ARRAYS = ("points", "normals", "colors", "target", "spacing")
#: Deflate makes at most 1032 bytes of each byte stored (zlib's documented limit).
DEFLATE_MAX_RATIO = 1032
#: What reading a damaged archive or member header raises in zipfile, zlib and numpy.
HEADER_ERRORS: tuple[type[BaseException], ...] = (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError,
                                                 NotImplementedError, RuntimeError, ValueError, TypeError,
                                                 zlib.error, struct.error, TokenError, SyntaxError, KeyError,
                                                 IndexError, UnicodeDecodeError, RecursionError, OverflowError)
#: numpy dtype kinds that are numbers (bool, signed, unsigned, float).
NUMERIC_KINDS = "biuf"
_KIND_WORDS = {"U": "text", "S": "bytes", "O": "Python objects (pickled)", "V": "records (a structured dtype)",
               "c": "complex numbers", "M": "dates", "m": "time spans"}


def read_npz_arrays(p: Path) -> dict[str, np.ndarray]:
    """The arrays of :data:`NPZ_ARRAYS` in the .npz file ``p`` (numbers only; absent ones left out).

    Raises:
        CloudError: the file is not a readable archive of numpy arrays, a member holds no numbers,
            or a member's header announces more (or less) data than the archive holds for it.
    """
    try:
        is_zip = zipfile.is_zipfile(p)
    except HEADER_ERRORS as exc:  # it looked at the end records and found them damaged
        raise CloudError(f"'{p}' is not a readable .npz file (damaged or truncated: {_first_line(exc)})") from None
    if not is_zip:
        raise CloudError(f"'{p}' is not an .npz file (a zip archive of named arrays); give a .npz with a "
                         "'points' array, or a .ply/.pcd file")
    size = p.stat().st_size
    arrays: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(p) as archive:
            members = {info.filename.removesuffix(".npy"): info for info in archive.infolist()}
            for name in NPZ_ARRAYS:
                if name in members:
                    arrays[name] = _read_member(p, archive, members[name], size)
            found = sorted(members)
    except CloudError:
        raise
    except HEADER_ERRORS as exc:
        raise CloudError(f"'{p}' is not a readable .npz file (damaged or truncated: {_first_line(exc)})") from None
    if "points" not in arrays:
        raise CloudError(f"'{p}' has no 'points' array (found {found[:8]})")
    return arrays


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:120] if text else type(exc).__name__


def npy_header(stream) -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype in the header of the .npy data in ``stream`` (left at the data's start).

    Raises:
        ValueError (or another of :data:`HEADER_ERRORS`): the stream holds no numpy array header.
    """
    version = np.lib.format.read_magic(stream)
    with quiet_numpy_header():
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
        else:
            raise ValueError(f"numpy format version {version}, which tactex does not read")
    return tuple(shape), dtype


@contextlib.contextmanager
def quiet_numpy_header() -> Iterator[None]:
    """numpy's warnings while it parses a .npy header ("required additional header parsing as it was
    created on Python 2", Python's "invalid escape sequence" in the header's text): about the file's
    age or damage, which the checks here report in their own words."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", SyntaxWarning)
        yield


def kind_words(dtype: np.dtype) -> str:
    """What an array of ``dtype`` holds, in words ("text", "complex numbers", ...)."""
    return _KIND_WORDS.get(dtype.kind, f"values of type {dtype}")


def _read_member(p: Path, archive: zipfile.ZipFile, info: zipfile.ZipInfo, size: int) -> np.ndarray:
    name = info.filename.removesuffix(".npy")
    where = f"'{p}': its '{name}' array"
    if info.flag_bits & 0x1:
        raise CloudError(f"{where} is encrypted; save the cloud again without a password (np.savez)")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise CloudError(f"{where} uses a zip compression numpy does not read; save it with np.savez or "
                         "np.savez_compressed")
    if info.compress_size > size or info.file_size > DEFLATE_MAX_RATIO * info.compress_size + 64:
        raise CloudError(f"{where} claims {info.file_size} bytes from {info.compress_size} stored in a file of "
                         f"{size}: the archive is damaged")
    with archive.open(info) as member:
        shape, dtype = npy_header(member)
        start = member.tell()
    if dtype.kind not in NUMERIC_KINDS:
        raise CloudError(f"{where} holds {kind_words(dtype)}: tactex reads only arrays of real numbers ('points', "
                         "'colors', ...)")
    need = math.prod(shape) * dtype.itemsize  # Python ints: a huge shape cannot overflow here
    held = info.file_size - start
    if need != held:
        more = "more" if need > held else "fewer"
        raise CloudError(f"{where} announces shape {tuple(shape)} of {dtype} ({need} bytes), {more} than the "
                         f"{held} bytes the file holds for it: the file is damaged")
    with archive.open(info) as member, quiet_numpy_header():
        return np.lib.format.read_array(member, allow_pickle=False)
