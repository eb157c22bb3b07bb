"""PCD headers of every version PCL writes (.5, .6, .7), handed to pypcd4 as version .7.

pypcd4 reads the data of all three (ascii, binary, binary_compressed are unchanged since .5) but
accepts only ``VERSION .7``: older headers lack COUNT (.5), WIDTH/HEIGHT (.5) or VIEWPOINT (.5, .6),
whose PCL defaults are filled in here — PCL's own ``test/bunny.pcd`` is a .5 file. A header that is
wrong in any other way is refused in one sentence naming the line, not pydantic's report.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

from tactex.errors import CloudError

__all__ = ["PCD_VERSIONS", "check_data", "normalised_header", "read_pcd"]

#: VERSION values read (PCL writes ".7"; some writers "0.7").
PCD_VERSIONS = {".5": "0.5", "0.5": "0.5", ".6": "0.6", "0.6": "0.6", ".7": "0.7", "0.7": "0.7"}
_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
#: The header ends with the DATA line; a longer run of text lines than this is not a PCD header.
_MAX_HEADER_LINES = 64


def _int(key: str, words: list[str]) -> int:
    try:
        value = int(words[0])
    except (IndexError, ValueError):
        raise CloudError(f"its {key} line needs a whole number, got '{' '.join(words)}'") from None
    if value < 0:
        raise CloudError(f"its {key} line must not be negative, got {value}")
    return value


def normalised_header(lines: list[str]) -> tuple[dict[str, list[str]], str]:
    """The header lines (without comments) as a dict of words, and the version the file gave."""
    head: dict[str, list[str]] = {}
    for line in lines:
        words = line.split()
        key = words[0].upper()
        if key not in _KEYS:
            raise CloudError(f"its header has an unknown line '{line[:40]}' (a PCD header has "
                             f"{', '.join(_KEYS)})")
        head[key] = words[1:]
    version = (head.get("VERSION") or ["0.7"])[0]
    if version not in PCD_VERSIONS:
        raise CloudError(f"its VERSION {version} is not one PCL writes (.5, .6 or .7)")
    for key in ("FIELDS", "SIZE", "TYPE", "DATA"):
        if not head.get(key):
            raise CloudError(f"its header has no {key} line")
    n = len(head["FIELDS"])
    head.setdefault("COUNT", ["1"] * n)
    for key in ("SIZE", "TYPE", "COUNT"):
        if len(head[key]) != n:
            raise CloudError(f"its header lists {n} FIELDS but {len(head[key])} {key} values")
    for size, kind in zip(head["SIZE"], head["TYPE"], strict=True):
        if kind.upper() not in ("F", "U", "I") or size not in ("1", "2", "4", "8") or (kind.upper() == "F"
                                                                                        and size not in ("4", "8")):
            raise CloudError(f"its header has a field of TYPE {kind} and SIZE {size}; PCD fields are F (4 or 8 "
                             "bytes), U or I (1, 2, 4 or 8 bytes)")
    for count in head["COUNT"]:
        if _int("COUNT", [count]) == 0:
            raise CloudError("its COUNT line has a 0: each field holds at least one value")
    for key in ("WIDTH", "HEIGHT", "POINTS"):
        if key in head:
            _int(key, head[key])
    if "POINTS" not in head and "WIDTH" not in head:
        raise CloudError("its header has neither POINTS nor WIDTH: the number of points is unknown")
    points = head.get("POINTS") or [str(_int("WIDTH", head["WIDTH"]) * _int("HEIGHT", head.get("HEIGHT", ["1"])))]
    head["POINTS"] = points
    head.setdefault("WIDTH", points)
    head.setdefault("HEIGHT", ["1"])
    head.setdefault("VIEWPOINT", ["0", "0", "0", "1", "0", "0", "0"])
    if len(head["VIEWPOINT"]) != 7:
        raise CloudError(f"its VIEWPOINT line needs 7 numbers, got {len(head['VIEWPOINT'])}")
    if head["DATA"][0].lower() not in ("ascii", "binary", "binary_compressed"):
        raise CloudError(f"its DATA is '{head['DATA'][0]}'; PCD data is ascii, binary or binary_compressed")
    head["DATA"] = [head["DATA"][0].lower()]
    head["TYPE"] = [t.upper() for t in head["TYPE"]]
    head["VERSION"] = ["0.7"]
    return head, PCD_VERSIONS[version]


#: LZF writes a run of up to 264 repeated bytes in 3 (88:1); no binary_compressed block expands more.
LZF_MAX_RATIO = 88


def check_data(head: dict[str, list[str]], body: bytes) -> None:
    """The data after a normalised header holds exactly the points it announces, checked before any
    array is allocated: an ascii file one line per point, a binary one POINTS × record bytes, a
    binary_compressed one a block whose sizes fit the file and the header (its uncompressed size is
    what pypcd4 allocates). Trailing whitespace aside, data past the points is refused too."""
    points = int(head["POINTS"][0])
    kind = head["DATA"][0]
    announced = f"its header announces {points} points"
    if kind == "ascii":
        rows = sum(1 for line in body.splitlines() if line.strip())
        if rows != points:
            why = "it is truncated, or" if rows < points else "it has rows past its points:"
            raise CloudError(f"{announced} but its ascii data has {rows} rows: {why} its POINTS line is wrong")
        return
    record = sum(int(s) * int(c) for s, c in zip(head["SIZE"], head["COUNT"], strict=True))
    need = points * record
    if kind == "binary":
        end = need
        if len(body) < need:
            raise CloudError(f"it is truncated: {announced} of {record} bytes ({need} bytes of binary data), the "
                             f"file holds {len(body)}")
    else:
        if points == 0 and not body.strip():
            return
        if len(body) < 8:
            raise CloudError(f"it is truncated: {announced} but its binary_compressed data has no block sizes")
        compressed, uncompressed = struct.unpack("<II", body[:8])
        if uncompressed != need:
            raise CloudError(f"{announced} of {record} bytes ({need} bytes), its compressed block says "
                             f"{uncompressed}: the header or the block is damaged")
        if compressed > len(body) - 8:
            raise CloudError(f"it is truncated: its compressed block has {compressed} bytes, the file holds "
                             f"{len(body) - 8}")
        if need > LZF_MAX_RATIO * compressed + 8:
            raise CloudError(f"its compressed block of {compressed} bytes cannot hold the {need} bytes {announced[4:]}"
                             ": the header or the block is damaged")
        end = 8 + compressed
    if body[end:].strip():
        raise CloudError(f"{announced} ({end} bytes of {kind} data), the file holds {len(body) - end} bytes more: "
                         "its POINTS line is wrong or the file is damaged")


def read_pcd(path: Path):
    """A :class:`pypcd4.PointCloud` of the PCD file at ``path`` (any version PCL writes)."""
    from pypcd4 import PointCloud

    raw = path.read_bytes()
    stream = io.BytesIO(raw)
    lines: list[str] = []
    for count, bline in enumerate(stream):
        if count > _MAX_HEADER_LINES:
            break
        try:
            line = bline.decode("ascii").strip()
        except UnicodeDecodeError:
            raise CloudError("it is not a PCD file: its header is not text (a PCD file starts with lines such "
                             "as 'VERSION .7', 'FIELDS x y z')") from None
        if not line or line.startswith("#"):
            continue
        lines.append(line)
        if line.upper().startswith("DATA"):
            break
    if not lines or not lines[-1].upper().startswith("DATA"):
        raise CloudError("it is not a PCD file: no header ending in a DATA line (a PCD file starts with lines "
                         "such as 'VERSION .7', 'FIELDS x y z' and ends its header with 'DATA ascii')")
    head, _ = normalised_header(lines)
    text = "".join(f"{key} {' '.join(head[key])}\n" for key in _KEYS)
    body = raw[stream.tell():]
    check_data(head, body)
    try:
        return PointCloud.from_fileobj(io.BytesIO(text.encode("ascii") + body))  # type: ignore[arg-type]
    except Exception as exc:  # pypcd4/pydantic/numpy/lzf raise many kinds on data that does not fit its header
        kind = head["DATA"][0]
        detail = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise CloudError(f"its {kind} data does not match its header ({head['POINTS'][0]} points of "
                         f"{' '.join(head['FIELDS'])}): {detail}") from None
