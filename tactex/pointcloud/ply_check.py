"""A PLY file's header checked against the file's size before plyfile reads its data.

plyfile sizes each element from its header's count (``np.empty(count, ...)``) before it reads a
byte of data: a count multiplied by a slip of an editor asks for gigabytes, a negative one fails deep
in numpy. Here every count is checked against the bytes the file holds, first: a binary element of
fixed-size rows fills exactly count × row bytes, one with list properties at least count × (its
scalars and list lengths); an ASCII element is count lines. Data past the last element (more rows
than the header says) is refused as well: the header is wrong, and which rows are meant is unknown.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from tactex.errors import CloudError

__all__ = ["read_ply"]

#: What plyfile raises on a file it cannot parse (OverflowError: an ASCII value outside its type).
_PLY_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, IndexError, KeyError, TypeError,
                                                 OverflowError, StopIteration)


#: Whitespace after a binary PLY's data that is tolerated (a newline some writers add) [bytes].
_MAX_TRAILING_SPACE = 64


def read_ply(p: Path):
    """The :class:`plyfile.PlyData` of the PLY file ``p``, its header's counts checked against the
    file's size before any data is read.

    Raises:
        CloudError: the file is not PLY, its header is malformed, or its data is shorter or longer
            than its header says (the message names the file and the element).
    """
    from plyfile import PlyData, PlyParseError

    size = p.stat().st_size
    try:
        with p.open("rb") as f:
            header = PlyData._parse_header(f)  # plyfile's own parser: the header read as it reads it
            start = f.tell()
            body = f.read() if header.text else b""  # a binary body is only measured, not read here
    except (PlyParseError, *_PLY_ERRORS) as exc:
        raise CloudError(f"'{p}' is not a readable PLY file: {_first_line(exc)}") from None
    for element in header.elements:
        if element.count < 0:
            raise CloudError(f"'{p}' is not a readable PLY file: its element '{element.name}' has a negative "
                             f"count ({element.count}) in its header")
    if header.text:
        _check_text(p, header, body)
    else:
        _check_binary(p, header, size - start)
    try:
        with warnings.catch_warnings():
            # plyfile reads an ASCII list with np.loadtxt, which warns when a list is empty (a valid list)
            warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
            ply, end, rest = _read(p, header.text, size)
    except (PlyParseError, *_PLY_ERRORS) as exc:
        raise CloudError(f"'{p}' is not a readable PLY file: {_first_line(exc)}") from None
    if not header.text and end < size and (rest.strip() or size - end > _MAX_TRAILING_SPACE):
        raise CloudError(f"'{p}' holds {size - end} bytes after the {_counts(header)} its header announces: "
                         "the header's counts are wrong (fix the 'element' lines) or the file is damaged")
    return ply


def _read(p: Path, text: bool, size: int):
    """plyfile's reading of ``p``; where a binary file's data end, and up to 64 bytes after them."""
    from plyfile import PlyData

    if text:  # plyfile wraps the file in a text reader, which closes it when done
        return PlyData.read(str(p)), size, b""
    with p.open("rb") as f:
        ply = PlyData.read(f)
        end = f.tell()
        return ply, end, f.read(_MAX_TRAILING_SPACE) if end < size else b""


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    if isinstance(exc, OverflowError):  # numpy: "Python integer 302 out of bounds for uint8"
        return f"a value in its data does not fit its property's type ({text.replace('Python integer ', '')})"
    return text.splitlines()[0][:160] if text else type(exc).__name__


def _counts(header) -> str:
    return ", ".join(f"{e.count} {e.name} rows" for e in header.elements) or "no rows"


def _check_text(p: Path, header, body: bytes) -> None:
    """An ASCII PLY holds one line per row of every element, in order (blank lines at the end aside)."""
    rows = sum(1 for line in body.splitlines() if line.strip())
    expected = sum(e.count for e in header.elements)
    if rows != expected:
        why = "it is truncated, or" if rows < expected else "it has rows past its elements' end:"
        raise CloudError(f"'{p}' is not a readable PLY file: its header announces {_counts(header)} ({expected} "
                         f"lines of data), the file holds {rows}: {why} the header's counts are wrong (fix the "
                         "'element' lines)")


def _check_binary(p: Path, header, size: int) -> None:
    """A binary PLY's elements fill count × row bytes; rows with lists at least their fixed part."""
    from plyfile import PlyListProperty

    least = 0
    exact = True
    for element in header.elements:
        row = 0
        for prop in element.properties:
            if isinstance(prop, PlyListProperty):
                exact = False
                row += np.dtype(prop.list_dtype(header.byte_order)[0]).itemsize  # its length; the items may be none
            else:
                row += np.dtype(prop.dtype(header.byte_order)).itemsize
        # a row of no bytes still costs plyfile a loop step: count it as one byte
        least += element.count * max(row, 1)
    if size < least:
        need = f"{least} bytes" if exact else f"at least {least} bytes"
        raise CloudError(f"'{p}' is not a readable PLY file: its header announces {_counts(header)} ({need} of "
                         f"binary data), the file holds {size}: it is truncated, or the header's counts are wrong")
