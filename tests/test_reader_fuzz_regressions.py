"""Every crash class the reader fuzzers (``make fuzz``, tools/fuzz/) found, and each size check up
front, as a file that must give one expected error naming it: a :mod:`tactex.errors` type, never
numpy's, zipfile's or trimesh's exception, never an allocation from a header's word, never output."""

from __future__ import annotations

import io
import json
import logging
import struct
import warnings
import zipfile

import numpy as np
import pytest

from tactex.errors import CloudError, ConfigError, InputError, TactexError
from tactex.experiments.study_spec import load_spec_file, spec_from_dict
from tactex.pointcloud import SurfaceCloud, save_ply
from tactex.pointcloud.io import read_cloud
from tactex.tasks.robot import load_hand_eye
from tests.format_fixtures import pcd_bytes


def _refused(path, *needles: str, kind: type[TactexError] = CloudError) -> str:
    with pytest.raises(kind) as info:
        read_cloud(path)
    message = str(info.value)
    assert f"'{path}'" in message
    for needle in needles:
        assert needle in message, message
    return message


def _write(tmp_path, name: str, data: bytes):
    path = tmp_path / name
    path.write_bytes(data)
    return path


# --- PLY: the header's counts against the file's bytes ----------------------------------------------


@pytest.fixture
def binary_ply(tmp_path) -> bytes:
    cloud = SurfaceCloud(points=np.random.default_rng(0).random((50, 3)) * 0.05, colors=np.full((50, 3), 0.5))
    return save_ply(cloud, tmp_path / "good.ply").read_bytes()


def test_binary_ply_longer_than_its_header(tmp_path, binary_ply) -> None:
    _refused(_write(tmp_path, "long.ply", binary_ply + b"\x01" * 64), "64 bytes after the 50 vertex rows")


def test_binary_ply_trailing_newline_is_fine(tmp_path, binary_ply) -> None:
    assert len(read_cloud(_write(tmp_path, "nl.ply", binary_ply + b"\n")).cloud) == 50


def test_binary_ply_shorter_than_its_header(tmp_path, binary_ply) -> None:
    _refused(_write(tmp_path, "short.ply", binary_ply[:-7]), "announces 50 vertex rows", "truncated")


def test_binary_mesh_ply_count_multiplied_is_refused_before_allocating(tmp_path) -> None:
    # a list property makes plyfile read row by row into np.empty(count): count × 1e9 was an allocation
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 3000000000\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
    body = np.zeros((3, 3), "<f4").tobytes() + struct.pack("<B3i", 3, 0, 1, 2)
    _refused(_write(tmp_path, "bomb.ply", head + body), "announces 3000000000 vertex rows", "holds 49")


def test_ascii_ply_more_rows_than_its_header(tmp_path) -> None:
    data = (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            b"end_header\n0 0 0\n1 1 1\n")
    _refused(_write(tmp_path, "more.ply", data), "announces 1 vertex rows", "holds 2")


def test_ply_vertex_coordinates_as_lists(tmp_path) -> None:
    data = (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nproperty float y\n"
            b"property float z\nend_header\n2 0 1 0 0\n")
    _refused(_write(tmp_path, "lists.ply", data), "properties x are lists")


def test_ply_value_outside_its_type(tmp_path) -> None:
    # fuzz: OverflowError at plyfile _from_fields (an uchar of 302)
    data = (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            b"property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n0 0 0 302 0 0\n")
    _refused(_write(tmp_path, "302.ply", data), "does not fit its property's type (302 out of bounds for uint8)")


def test_ply_empty_ascii_list_warns_nothing(tmp_path) -> None:
    # fuzz (a warning, shown by the CLI as numpy's words): plyfile's np.loadtxt of an empty list
    data = (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
            b"property list uchar int tags\nend_header\n0 0 0 0\n0.01 0 0 1 7\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(read_cloud(_write(tmp_path, "tags.ply", data)).cloud) == 2


# --- PCD: the data against POINTS ----------------------------------------------------------------------


def _pcd(encoding: str, n: int = 40) -> bytes:
    # rounded coordinates: LZF compresses them (it returns nothing for data it cannot shrink)
    return pcd_bytes(np.round(np.random.default_rng(0).random((n, 3)) * 0.05, 2), ".7", encoding)


def test_ascii_pcd_longer_than_its_points(tmp_path) -> None:
    _refused(_write(tmp_path, "a.pcd", _pcd("ascii").replace(b"POINTS 40", b"POINTS 10")), "has 40 rows")


def test_binary_pcd_longer_than_its_points(tmp_path) -> None:
    _refused(_write(tmp_path, "b.pcd", _pcd("binary") + b"\x07" * 12), "12 bytes more")


def test_binary_compressed_pcd_size_bomb(tmp_path) -> None:
    # pypcd4 allocates the uncompressed size the block announces (up to 4 GiB) before decompressing
    data = _pcd("binary_compressed")
    head, _, rest = data.partition(b"DATA binary_compressed\n")
    compressed, _ = struct.unpack("<II", rest[:8])
    bomb = head.replace(b"POINTS 40", b"POINTS 300000000").replace(b"WIDTH 40", b"WIDTH 300000000")
    bomb += b"DATA binary_compressed\n" + struct.pack("<II", compressed, 300000000 * 12) + rest[8:]
    _refused(_write(tmp_path, "c.pcd", bomb), "cannot hold the 3600000000 bytes")


def test_binary_compressed_pcd_truncated_block(tmp_path) -> None:
    _refused(_write(tmp_path, "t.pcd", _pcd("binary_compressed")[:-20]), "truncated")


def test_signalling_nan_is_dropped_without_numpy_warning(tmp_path) -> None:
    # fuzz (a warning, 37 inputs in the binary PCD run): widening a float32 sNaN warns "invalid value
    # encountered in cast"; the point is dropped and counted like any NaN
    data = _pcd("binary")
    start = data.index(b"DATA binary\n") + len(b"DATA binary\n")
    data = data[:start] + struct.pack("<I", 0x7F800001) + data[start + 4:]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = read_cloud(_write(tmp_path, "snan.pcd", data))
    assert (len(got.cloud), got.n_dropped) == (39, 1)


def test_pcd_count_not_a_number(tmp_path) -> None:
    # fuzz: ValueError at pcd_header <genexpr> (int() of a COUNT word)
    data = _pcd("binary").replace(b"COUNT 1 1 1", b"COUNT 1 1 ?")
    _refused(_write(tmp_path, "count.pcd", data), "COUNT line needs a whole number")


# --- NPZ: headers, types and the zip features numpy does not read --------------------------------------


def _npz_with(tmp_path, name: str, member: bytes, *, compress: int = zipfile.ZIP_STORED):
    path = tmp_path / name
    with zipfile.ZipFile(path, "w", compression=compress) as z:
        z.writestr("points.npy", member)
    return path


def _npy_bytes(shape: tuple[int, ...], descr: str, data: bytes) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue() + data


#: A .npy header whose dict ends inside a string: numpy's parser raises tokenize.TokenError.
_UNTERMINATED_HEADER = b"\x93NUMPY\x01\x00" + struct.pack("<H", 52) + b"{'descr': '<f8', 'fortran_order" + bytes(21)


def test_npz_shape_bomb_is_refused_before_allocating(tmp_path) -> None:
    # np.load allocated 224 GiB for the shape in a 1 kB file
    path = _npz_with(tmp_path, "bomb.npz", _npy_bytes((10**10, 3), "<f8", b"\0" * 1200))
    _refused(path, "announces shape (10000000000, 3)", "1200 bytes")


def test_npz_deflate_bomb_claim_is_refused(tmp_path) -> None:
    path = _npz_with(tmp_path, "ratio.npz", _npy_bytes((100, 3), "<f8", b"\0" * 2400), compress=zipfile.ZIP_DEFLATED)
    raw = bytearray(path.read_bytes())
    # the central directory's uncompressed size, raised to a claim deflate cannot make of the stored bytes
    at = raw.rfind(b"PK\x01\x02") + 24
    raw[at:at + 4] = struct.pack("<I", 10**9)
    path.write_bytes(bytes(raw))
    _refused(path, "claims 1000000000 bytes")


@pytest.mark.parametrize(("values", "words"), [(np.ones((4, 3), complex), "complex numbers"),
                                               (np.zeros(4, [("x", "f8")]), "records"),
                                               (np.array([["a", "b", "c"]]), "text")])
def test_npz_arrays_that_are_not_real_numbers(tmp_path, values, words) -> None:
    path = tmp_path / "kinds.npz"
    np.savez(path, points=values)
    _refused(path, f"holds {words}")


def test_npz_encrypted_member(tmp_path) -> None:
    # fuzz: RuntimeError at zipfile open ("password required")
    path = _npz_with(tmp_path, "enc.npz", _npy_bytes((1, 3), "<f8", b"\0" * 24))
    raw = bytearray(path.read_bytes())
    for sig, offset in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):  # the flag bits of both headers
        at = raw.find(sig) + offset
        raw[at] |= 0x1
    path.write_bytes(bytes(raw))
    _refused(path, "encrypted")


@pytest.mark.parametrize(("field", "value", "needle"), [
    # fuzz: NotImplementedError at zipfile _check_compression: a compression method numpy does not read
    ((8, 10), struct.pack("<H", 99), "compression numpy does not read"),
    # fuzz: NotImplementedError at zipfile _RealGetContents: "zip file version 7.6" (version needed)
    ((4, 6), struct.pack("<H", 76), "not a readable .npz file"),
    # fuzz: NotImplementedError at zipfile open: "compressed patched data (flag bit 5)"
    ((6, 8), struct.pack("<H", 0x20), "not a readable .npz file"),
])
def test_npz_zip_features_numpy_does_not_read(tmp_path, field, value, needle) -> None:
    path = _npz_with(tmp_path, "lz.npz", _npy_bytes((1, 3), "<f8", b"\0" * 24))
    raw = bytearray(path.read_bytes())
    for sig, offset in zip((b"PK\x03\x04", b"PK\x01\x02"), field, strict=True):  # the local and central headers
        at = raw.find(sig) + offset
        raw[at:at + 2] = value
    path.write_bytes(bytes(raw))
    _refused(path, needle)


def test_npz_damaged_deflate_stream(tmp_path) -> None:
    # fuzz: zlib.error at zipfile _read1 ("invalid distance too far back")
    path = tmp_path / "z.npz"
    np.savez_compressed(path, points=np.random.default_rng(0).random((200, 3)))
    raw = bytearray(path.read_bytes())
    start = raw.find(b"PK\x03\x04") + 30 + len("points.npy")
    for i in range(start + 40, start + 80):
        raw[i] ^= 0x5A
    path.write_bytes(bytes(raw))
    _refused(path, "not a readable .npz file")


def test_npz_multi_disk_end_record(tmp_path) -> None:
    # fuzz: BadZipFile at zipfile _EndRecData64, raised through zipfile.is_zipfile itself
    data = b"PK\x06\x07" + struct.pack("<IQI", 0, 0, 2) + b"PK\x05\x06" + bytes(18)
    _refused(_write(tmp_path, "disks.npz", data), "span multiple disks")


def test_npz_damaged_member_header(tmp_path) -> None:
    # fuzz: TokenError at tokenize (numpy parsing a header dict cut short)
    member = _UNTERMINATED_HEADER + b"\0" * 24
    _refused(_npz_with(tmp_path, "tok.npz", member), "not a readable .npz file")


# --- meshes: trimesh quiet, its errors ours ----------------------------------------------------------


_OBJ_BODY = (b"v 0 0 0\nv 0.055 0\nvt 0 0\nvt\x001 0\nvt 0 1\nf 1/1 2/2 3/.05 0 0\nv 0 0.05 0\nvt 0 0\nvt\x001 0\n"
             b"vt 0 1\n")


@pytest.mark.parametrize("data", [
    # fuzz: ValueError at trimesh sample_surface ("cannot reshape array of size 16 into shape (2,3)")
    b"mtllib missing.mtl\nusemtl skin\n" + _OBJ_BODY + b"f 1/1 2/2 3/3\n",
    # fuzz: ValueError at trimesh caching __isub__ ("operands could not be broadcast together")
    b"\0\0ib missing.mtl\nusemtl skin\n" + _OBJ_BODY + b"f 1",
])
def test_obj_faces_that_are_not_triangles(tmp_path, capsys, data) -> None:
    _refused(_write(tmp_path, "bad.obj", data), "not a readable mesh")
    assert capsys.readouterr().err == ""


def test_trimesh_logs_nothing_and_is_restored(tmp_path, caplog, capsys) -> None:
    data = b"mtllib missing.mtl\nusemtl skin\nv 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    logger = logging.getLogger("trimesh")
    before = (logger.propagate, logger.level, list(logger.handlers))
    with caplog.at_level(logging.DEBUG):
        got = read_cloud(_write(tmp_path, "tex.obj", data))
    assert not [r for r in caplog.records if r.name.startswith("trimesh")]
    assert capsys.readouterr().err == ""
    assert len(got.cloud) > 0
    assert (logger.propagate, logger.level, list(logger.handlers)) == before


# --- the hand-eye file ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("text", "needle"), [("[" * 20_000, "not a JSON nested list"),  # RecursionError
                                              (f"[[{10**400}]]", "not a JSON nested list"),  # OverflowError
                                              ('[[{"a": 1}]]', "not a JSON nested list"),
                                              (b"\xf0\x28", "not a JSON nested list")])  # UnicodeDecodeError
def test_hand_eye_json_that_is_not_numbers(tmp_path, text, needle) -> None:
    path = tmp_path / "he.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(InputError, match=needle) as info:
        load_hand_eye(path)
    assert f"'{path}'" in str(info.value)


def test_hand_eye_json_too_big(tmp_path) -> None:
    path = tmp_path / "big.json"
    path.write_text(json.dumps([[0.0] * 4] * 4) + " " * 70_000)
    with pytest.raises(InputError, match="bytes: not a 4×4 transform"):
        load_hand_eye(path)


@pytest.mark.parametrize(("member", "needle"), [
    (_npy_bytes((10**9, 4), "<f8", b"\0" * 128), r"shape \(1000000000, 4\)"),  # fromfile of the header's count
    (_npy_bytes((4, 4), "<U8", b"\0" * 512), "holds text"),  # np.asarray(float) of strings: ValueError
    (_npy_bytes((4, 4), "<f8", b"\0" * 100), "damaged or truncated"),  # fewer bytes than 4×4
    (_UNTERMINATED_HEADER + b"\0" * 128, "is not a .npy array"),  # fuzz: TokenError at tokenize
    (b"", "is not a .npy array"),  # fuzz: EOFError at np.load (an empty file)
])
def test_hand_eye_npy_checked_before_reading(tmp_path, member, needle) -> None:
    path = tmp_path / "he.npy"
    path.write_bytes(member)
    with pytest.raises(InputError, match=needle) as info:
        load_hand_eye(path)
    assert f"'{path}'" in str(info.value)


def _npy_with_header(text: bytes) -> bytes:
    text = text.ljust(118) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text + bytes(128)


@pytest.mark.parametrize(("name", "data", "needle"), [
    # numpy: "required additional header parsing as it was created on Python 2" (a UserWarning)
    ("py2.npy", _npy_with_header(b"{'descr': '<f8', 'fortran_order': False, 'shape': (4L, 5L), }"), "shape (4, 5)"),
    # Python: "invalid escape sequence" compiling the header's text (a DeprecationWarning)
    ("escape.npy", _npy_with_header(b"{'descr': '<f\\p8', 'fortran_order': False, 'shape': (4, 4), }"),
     "is not a .npy array"),
    # numpy: "overflow encountered in matmul" checking that huge numbers are a rotation
    ("huge.json", json.dumps([[1e200] * 4] * 3 + [[0, 0, 0, 1]]).encode(), "4×4 rigid transform"),
])
def test_hand_eye_refusals_warn_nothing(tmp_path, name, data, needle) -> None:
    # fuzz: warnings the CLI would have shown in numpy's and Python's words (59, 52 and 6 inputs)
    path = tmp_path / name
    path.write_bytes(data)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(InputError) as info:
            load_hand_eye(path)
    assert needle in str(info.value)
    assert not caught, [str(w.message) for w in caught]


# --- the study spec --------------------------------------------------------------------------------------


@pytest.mark.parametrize(("toml", "needle"), [
    ('task = {uniform = [50, 200]}\n', "unknown study task"),  # fuzz: TypeError (a dict is unhashable)
    ("seeds = 1" + "0" * 80 + "\n", "seeds must be a count from 1 to"),  # fuzz: OverflowError in range()
    ("seeds = 10000\n[grid]\ntool_friction = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]\n"
     "budget_s = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0]\n", "plans 1,200,000 runs"),
    ('[grid]\nbaseline = [{a = 1}, "raster"]\n', "is not a single value"),  # TypeError: unhashable
    # fuzz (confirmation round): 444,440 draws × 2 seeds took over 5 s of CPU to list
    ('seeds = [0, 3]\ndraws = 60000\n[random]\nforce_n = {uniform = [0, 3]}\n', "plans 120,000 runs"),
    ('draws = 2\n[random]\nbaseline = {uniform = ["a", "b"]}\n', "draws numbers"),  # float('a'): ValueError
    ('[success]\nat_least = "most"\n', "at_least must be a number"),  # math.isnan(str): TypeError
    ('[success]\nmetric = 3\n', "metric must be a metric's name"),
    ('draws = 1\ndraw_seed = -1\n[random]\nforce_n = {uniform = [1.0, 2.0]}\n', "draw_seed must be"),
    # fuzz (long round): ValueError "high is out of bounds for int64" in numpy's integers draw
    ('task = "wipe"\ndraws = 3\n[random]\ncommand_delay_ticks = {integers = [0, 3' + "3" * 40 + ']}\n', "too wide"),
    # numpy's uniform: OverflowError "high - low range exceeds valid bounds"
    ('draws = 3\n[random]\nforce_n = {uniform = [-1e308, 1e308]}\n', "too wide"),
])
def test_study_spec_mistakes_are_config_errors(tmp_path, toml, needle) -> None:
    path = tmp_path / "study.toml"
    path.write_text(toml)
    with pytest.raises((ConfigError, InputError), match=needle):
        spec_from_dict(load_spec_file(path))
