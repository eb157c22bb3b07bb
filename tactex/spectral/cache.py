"""On-disk cache of Laplace bases: one ``.npz`` per (points, parameters), never pickled.

A basis file is named by its key, the SHA-256 of the points and of every parameter that changes
the result. :func:`load_basis` raises :class:`CacheError` on a corrupt or mismatching file;
:func:`tactex.spectral.build_basis` catches that, warns, recomputes and overwrites the file.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from tactex.errors import CacheError

__all__ = ["CACHE_ENV", "FORMAT_VERSION", "basis_key", "default_cache_dir", "load_arrays", "save_arrays"]

#: Environment variable overriding the default cache directory.
CACHE_ENV = "TACTEX_CACHE_DIR"
#: Bump when the solver or the file layout changes: old files then simply stop matching.
FORMAT_VERSION = 2


def default_cache_dir() -> Path:
    """``$TACTEX_CACHE_DIR`` if set, else ``~/.cache/tactex/basis``."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "tactex" / "basis"


def basis_key(points: np.ndarray, n_eigen: int, n_neighbors: int, mollify_factor: float, spacing: float,
              eigensolver: str = "arpack", eigen_tol: float = 0.0) -> str:
    """Content hash of the points [m] and of the parameters that define the basis, including the
    spacing h [m] it stores (the same points filtered with another voxel size keep another h) and
    the eigensolver with its tolerance (an approximate basis never stands in for the exact one)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(points, dtype=np.float64).tobytes())
    h.update(f"|N={points.shape[0]}|K={n_eigen}|nn={n_neighbors}|mollify={mollify_factor!r}|h={float(spacing)!r}"
             f"|solver={eigensolver}|tol={float(eigen_tol)!r}|v{FORMAT_VERSION}".encode())
    return h.hexdigest()


def save_arrays(path: Path, L: sp.csr_matrix, arrays: dict[str, np.ndarray]) -> None:
    """Write L (as CSR parts) and the arrays to ``path`` atomically (no half-written file is ever read)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    L = sp.csr_matrix(L)
    payload = {
        "L_data": L.data,
        "L_indices": L.indices,
        "L_indptr": L.indptr,
        "L_shape": np.asarray(L.shape, dtype=np.int64),
        "format_version": np.asarray(FORMAT_VERSION),
        **arrays,
    }
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **payload)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_arrays(path: Path) -> tuple[sp.csr_matrix, dict[str, np.ndarray]]:
    """Read a file written by :func:`save_arrays`; :class:`CacheError` if unreadable or inconsistent."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {name: np.array(z[name]) for name in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as exc:
        raise CacheError(f"basis cache file '{path}' is unreadable ({exc}); delete it") from exc
    try:
        version = int(arrays.pop("format_version"))
        if version != FORMAT_VERSION:
            raise CacheError(f"basis cache file '{path}' has format {version}, expected {FORMAT_VERSION}")
        shape = tuple(int(v) for v in arrays.pop("L_shape"))
        L = sp.csr_matrix((arrays.pop("L_data"), arrays.pop("L_indices"), arrays.pop("L_indptr")), shape=shape)
    except CacheError:
        raise
    except (KeyError, ValueError, TypeError, IndexError) as exc:
        raise CacheError(f"basis cache file '{path}' is inconsistent ({exc}); delete it") from exc
    return L, arrays
