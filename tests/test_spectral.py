"""Spectral basis: operator properties, analytic eigenvalues, diffusion, cache, input checks."""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

from tactex.errors import CacheError, CloudError, ConfigError, InputError, SpectralError
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import (
    ImplicitDiffusion,
    SpectralDiffusion,
    build_basis,
    diffusion_timestep,
    laplace_eigenpairs,
    load_basis,
    point_cloud_laplacian,
    save_basis,
)
from tactex.spectral import exact as exact_mod

EIG_RTOL = 0.05  # analytic vs discrete Neumann eigenvalues (brief: within 5 %)
MASS_RTOL = 1e-9  # ∫u preserved by the Neumann diffusion
ORTHO_TOL = 1e-9  # Φᵀ M Φ = I


def square_grid(n: int, side_m: float, jitter: float = 0.0, seed: int = 0) -> np.ndarray:
    """n×n points on the flat square [0, side]² (z = 0), optionally jittered in-plane."""
    g = np.linspace(0.0, side_m, n)
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    if jitter:
        h = side_m / (n - 1)
        inner = (pts[:, 0] > 0) & (pts[:, 0] < side_m) & (pts[:, 1] > 0) & (pts[:, 1] < side_m)
        rng = np.random.default_rng(seed)
        pts[inner, :2] += rng.uniform(-jitter * h, jitter * h, size=(int(inner.sum()), 2))
    return pts


def curved_patch(n: int = 20, seed: int = 1) -> np.ndarray:
    """A bumpy, jittered 0.1 m patch: a generic curved surface."""
    pts = square_grid(n, 0.1, jitter=0.3, seed=seed)
    pts[:, 2] = 0.01 * np.sin(30 * pts[:, 0]) * np.cos(20 * pts[:, 1])
    return pts


@pytest.fixture(scope="module")
def patch_cloud() -> SurfaceCloud:
    return SurfaceCloud(points=curved_patch())


@pytest.fixture(scope="module")
def patch_basis(patch_cloud: SurfaceCloud):
    return build_basis(patch_cloud, n_eigen=60, cache=False)


# --- operators ---------------------------------------------------------------------------------


def test_laplacian_symmetric_zero_row_sums_positive_mass() -> None:
    L, M = point_cloud_laplacian(curved_patch())
    scale = abs(L).max()
    assert abs(L - L.T).max() <= 1e-12 * scale
    assert np.abs(np.asarray(L.sum(axis=1))).max() <= 1e-10 * scale
    offdiag = (L - sp.diags(L.diagonal())).toarray()
    assert abs(M - sp.diags(M.diagonal())).max() == 0.0  # M is diagonal
    assert np.all(M.diagonal() > 0.0)
    # Intrinsic Delaunay weights: off-diagonal entries are ≤ 0 (maximum principle).
    assert offdiag.max() <= 1e-12 * scale
    # The total mass is the area of the patch (≥ its flat 0.1 m × 0.1 m footprint).
    assert 0.01 <= M.diagonal().sum() <= 0.0125


def test_flat_square_matches_analytic_neumann_eigenvalues() -> None:
    side = 0.1
    basis = build_basis(SurfaceCloud(points=square_grid(40, side, jitter=0.2)), n_eigen=10, cache=False)
    modes = sorted(m * m + n * n for m in range(5) for n in range(5))[:10]
    analytic = np.pi**2 * np.asarray(modes, dtype=float) / side**2
    assert basis.evals[0] <= 1e-8 * analytic[1]
    np.testing.assert_allclose(basis.evals[1:], analytic[1:], rtol=EIG_RTOL)


def test_eigenvectors_m_orthonormal_and_ascending(patch_basis) -> None:
    b = patch_basis
    gram = b.evecs.T @ (b.mass[:, None] * b.evecs)
    np.testing.assert_allclose(gram, np.eye(b.n_eigen), atol=ORTHO_TOL)
    assert np.all(np.diff(b.evals) >= 0.0) and b.evals[0] >= 0.0
    residual = b.L @ b.evecs - (b.mass[:, None] * b.evecs) * b.evals
    assert np.abs(residual).max() <= 1e-8 * np.abs(b.L @ b.evecs).max()
    assert b.n_components == 1 and b.n_points == 400 and b.n_eigen == 60


def test_sparse_and_dense_solvers_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    L, M = point_cloud_laplacian(curved_patch(30))
    monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10_000)
    dense_vals, dense_vecs = laplace_eigenpairs(L, M, 20)
    monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10)
    sparse_vals, sparse_vecs = laplace_eigenpairs(L, M, 20)
    np.testing.assert_allclose(sparse_vals, dense_vals, rtol=1e-8, atol=1e-8 * dense_vals[-1])
    # Eigenvectors of simple eigenvalues agree up to sign (sign fixed by convention).
    simple = np.flatnonzero(np.diff(dense_vals[:-1]) > 1e-3 * dense_vals[-1]) + 1
    for k in simple:
        assert np.abs(np.abs(dense_vecs[:, k] @ (M @ sparse_vecs[:, k])) - 1.0) < 1e-6


def test_restarted_lanczos_matches_dense_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    # k = 100 on ~1000 points: ARPACK's basis (1.5 k) is smaller than the ≈ 2.5 k Krylov vectors the
    # 100th pair needs, so the implicit restarts are exercised, as on the TEC clouds.
    L, M = point_cloud_laplacian(curved_patch(32, seed=3))
    k = 100
    assert exact_mod.lanczos_basis_size(k, L.shape[0]) < 2.5 * k
    monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10_000)
    ref_vals, ref_vecs = laplace_eigenpairs(L, M, k)
    monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10)
    vals, vecs = laplace_eigenpairs(L, M, k)
    mass = M.diagonal()
    np.testing.assert_allclose(vals, ref_vals, rtol=1e-9, atol=1e-9 * ref_vals[-1])
    # Same spanned space: the M-orthogonal projection of the reference basis onto ours loses nothing.
    overlap = ref_vecs.T @ (mass[:, None] * vecs)
    np.testing.assert_allclose(np.linalg.svd(overlap, compute_uv=False), 1.0, atol=1e-8)
    # Hence the same diffusion operator (TEC eq. 19) at the paper's α = 10.
    dt = diffusion_timestep(10.0, 0.1 / 31)
    u = np.random.default_rng(4).random(L.shape[0])
    step = lambda V, w: V @ (np.exp(-w * dt) * (V.T @ (mass * u)))  # noqa: E731
    np.testing.assert_allclose(step(vecs, vals), step(ref_vecs, ref_vals), rtol=0, atol=1e-10 * np.abs(u).max())


@pytest.mark.parametrize(("k", "n"), [(1, 5000), (10, 5000), (100, 5000), (200, 300), (3000, 4001), (4000, 4001)])
def test_lanczos_basis_size_within_arpack_bounds(k: int, n: int) -> None:
    ncv = exact_mod.lanczos_basis_size(k, n)
    assert k < ncv <= n
    assert ncv >= min(n, 20)


def test_components_follow_the_cloud() -> None:
    a = curved_patch(15)
    b = a + np.array([1.0, 0.0, 0.0])  # a second patch far away
    basis = build_basis(SurfaceCloud(points=np.vstack([a, b])), n_eigen=5, n_neighbors=10, cache=False)
    assert basis.n_components == 2
    assert basis.evals[1] <= 1e-8 * basis.evals[2]  # one zero eigenvalue per part


def test_a_stored_zero_weight_joins_no_parts() -> None:
    from tactex.spectral.basis import _component_labels

    # Two pairs of points, the pairs linked only by a stored zero weight (0-2 and 2-0).
    rows = np.array([0, 0, 0, 1, 1, 2, 2, 2, 3, 3])
    cols = np.array([0, 1, 2, 0, 1, 0, 2, 3, 2, 3])
    vals = np.array([1.0, -1.0, 0.0, -1.0, 1.0, 0.0, 2.0, -2.0, -2.0, 2.0])
    L = sp.csr_matrix((vals, cols, np.searchsorted(rows, np.arange(5))), shape=(4, 4))
    n, labels = _component_labels(L)
    assert n == 2 and labels[0] == labels[1] != labels[2] == labels[3]
    assert L.nnz == 10  # the matrix itself is left as it was


# --- diffusion ---------------------------------------------------------------------------------


def test_diffusion_timestep_is_alpha_h_squared() -> None:
    assert diffusion_timestep(10.0, 0.003) == pytest.approx(10.0 * 0.003**2, rel=1e-15)


@pytest.mark.parametrize("cls", ["spectral", "implicit"])
def test_diffusion_preserves_integral(patch_basis, cls: str, rng: np.random.Generator) -> None:
    b = patch_basis
    dt = diffusion_timestep(10.0, b.spacing)
    step = SpectralDiffusion(b, dt) if cls == "spectral" else ImplicitDiffusion(b.L, b.M, dt)
    u = rng.random(b.n_points)
    total = b.mass @ u
    for _ in range(20):
        u = step(u)
    assert abs(b.mass @ u - total) <= MASS_RTOL * total
    # Diffusion smooths: the spread shrinks and stays within the initial bounds.
    assert u.min() >= 0.0 and u.std() < 0.5


def test_spectral_diffusion_approaches_implicit_as_basis_grows(rng: np.random.Generator) -> None:
    cloud = SurfaceCloud(points=curved_patch(20))
    u = rng.random(len(cloud))
    full = build_basis(cloud, n_eigen=len(cloud) - 1, cache=False)
    dt = diffusion_timestep(10.0, cloud.spacing)
    mass_norm = lambda v: float(np.sqrt(full.mass @ v**2))  # noqa: E731
    implicit = ImplicitDiffusion(full.L, full.M, dt)(u)
    exact = ImplicitDiffusion(full.L, full.M, dt, substeps=4000)(u)
    errors, errors_exact = [], []
    for k in (10, 25, 50, 100, 200, len(cloud) - 1):
        b = build_basis(cloud, n_eigen=k, cache=False)
        v = SpectralDiffusion(b, dt)(u)
        errors.append(mass_norm(v - implicit))
        errors_exact.append(mass_norm(v - exact))
    assert all(e1 < e0 for e0, e1 in itertools.pairwise(errors)), errors
    # Against the (sub-stepped) exact flow the error falls until it meets the reference's own error.
    slack = 1e-9 * mass_norm(exact)
    assert all(e1 <= e0 + slack for e0, e1 in itertools.pairwise(errors_exact)), errors_exact
    assert errors_exact[2] < 0.01 * errors_exact[0]
    # With (almost) the whole spectrum the spectral step is the exact flow e^{−δt M⁻¹L} u.
    assert errors_exact[-1] <= 1e-3 * mass_norm(exact)


def test_diffusion_handles_batches(patch_basis, rng: np.random.Generator) -> None:
    step = SpectralDiffusion.from_alpha(patch_basis, 5.0)
    u = rng.random((patch_basis.n_points, 3))
    out = step(u)
    np.testing.assert_allclose(out[:, 1], step(u[:, 1]), rtol=1e-12, atol=1e-15)


# --- cache -------------------------------------------------------------------------------------


def test_cache_round_trip(tmp_path, patch_cloud, monkeypatch: pytest.MonkeyPatch) -> None:
    first = build_basis(patch_cloud, n_eigen=20, cache_dir=tmp_path)
    files = list(tmp_path.glob("*.npz"))
    assert [f.stem for f in files] == [first.key]
    import tactex.spectral.basis as basis_mod

    def fail(*a, **k):
        raise AssertionError("recomputed although a valid cache file exists")

    monkeypatch.setattr(basis_mod, "compute_basis", fail)
    second = build_basis(patch_cloud, n_eigen=20, cache_dir=tmp_path)
    np.testing.assert_array_equal(second.evecs, first.evecs)
    np.testing.assert_array_equal(second.evals, first.evals)
    np.testing.assert_array_equal(second.L.toarray(), first.L.toarray())
    assert second.spacing == first.spacing and second.key == first.key and second.n_neighbors == 30
    assert second.from_cache and not first.from_cache


def test_cache_key_depends_on_points_and_parameters(tmp_path, patch_cloud) -> None:
    a = build_basis(patch_cloud, n_eigen=10, cache_dir=tmp_path)
    b = build_basis(patch_cloud, n_eigen=11, cache_dir=tmp_path)
    c = build_basis(patch_cloud, n_eigen=10, n_neighbors=20, cache_dir=tmp_path)
    moved = patch_cloud.transformed(np.eye(3), np.array([0.0, 0.0, 1e-3]))
    d = build_basis(moved, n_eigen=10, cache_dir=tmp_path)
    coarser = SurfaceCloud(points=patch_cloud.points, spacing=1.5 * patch_cloud.spacing)
    e = build_basis(coarser, n_eigen=10, cache_dir=tmp_path)  # the same points, another h
    assert len({a.key, b.key, c.key, d.key, e.key}) == 5
    assert not e.from_cache and e.spacing == coarser.spacing
    assert len(list(tmp_path.glob("*.npz"))) == 5


def test_default_cache_dir_from_environment(tmp_path, patch_cloud, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTEX_CACHE_DIR", str(tmp_path / "envcache"))
    b = build_basis(patch_cloud, n_eigen=5)
    assert (tmp_path / "envcache" / f"{b.key}.npz").is_file()


def test_corrupt_cache_file_warns_and_recomputes(tmp_path, patch_cloud) -> None:
    good = build_basis(patch_cloud, n_eigen=8, cache_dir=tmp_path)
    path = tmp_path / f"{good.key}.npz"
    path.write_bytes(b"not a zip file at all")
    with pytest.raises(CacheError, match="unreadable"):
        load_basis(path)
    with pytest.warns(RuntimeWarning, match="recomputing"):
        again = build_basis(patch_cloud, n_eigen=8, cache_dir=tmp_path)
    np.testing.assert_allclose(again.evals, good.evals, rtol=1e-10)
    assert load_basis(path, expected_key=good.key).n_eigen == 8  # the file was rewritten


def test_mismatching_cache_file(tmp_path, patch_cloud) -> None:
    other = build_basis(patch_cloud, n_eigen=6, cache=False)
    target = build_basis(patch_cloud, n_eigen=8, cache=False)
    path = tmp_path / f"{target.key}.npz"
    save_basis(other, path)  # a valid file under the wrong name
    with pytest.raises(CacheError, match="other points or parameters"):
        load_basis(path, expected_key=target.key)
    with pytest.warns(RuntimeWarning):
        got = build_basis(patch_cloud, n_eigen=8, cache_dir=tmp_path)
    assert got.n_eigen == 8


def test_cache_file_with_inconsistent_arrays(tmp_path, patch_basis) -> None:
    path = save_basis(patch_basis, tmp_path / "b.npz")
    with np.load(path, allow_pickle=False) as z:
        arrays = dict(z)
    arrays["evecs"] = arrays["evecs"][:-1]
    np.savez(path, **arrays)
    with pytest.raises(CacheError, match="inconsistent shapes"):
        load_basis(path)
    del arrays["evals"]
    np.savez(path, **arrays)
    with pytest.raises(CacheError, match="lacks"):
        load_basis(path)


def test_cache_file_with_nan(tmp_path, patch_basis) -> None:
    path = save_basis(patch_basis, tmp_path / "b.npz")
    with np.load(path, allow_pickle=False) as z:
        arrays = dict(z)
    arrays["evals"] = arrays["evals"].copy()
    arrays["evals"][3] = np.nan
    np.savez(path, **arrays)
    with pytest.raises(CacheError, match="NaN"):
        load_basis(path)


# --- bad input ---------------------------------------------------------------------------------


def test_empty_cloud_is_refused() -> None:
    with pytest.raises(CloudError, match="empty"):
        point_cloud_laplacian(np.zeros((0, 3)))


def test_nan_points_are_refused() -> None:
    pts = curved_patch(10)
    pts[7, 1] = np.nan
    with pytest.raises(CloudError, match="NaN"):
        point_cloud_laplacian(pts)


def test_duplicates_are_refused_with_a_hint() -> None:
    pts = curved_patch(10)
    pts = np.vstack([pts, pts[3:5]])
    with pytest.raises(CloudError, match=r"2 duplicated.*deduplicated\(\)"):
        point_cloud_laplacian(pts)
    cloud = SurfaceCloud(points=pts, spacing=0.01)
    with pytest.raises(CloudError, match="duplicated"):
        build_basis(cloud, n_eigen=5, cache=False)
    assert build_basis(cloud.deduplicated(), n_eigen=5, cache=False).n_points == 100


def test_too_few_points_for_the_neighbourhood() -> None:
    pts = curved_patch(5)  # 25 points
    with pytest.raises(CloudError, match=r"25 point\(s\).*n_neighbors=30.*at least 31"):
        point_cloud_laplacian(pts)
    assert point_cloud_laplacian(pts, n_neighbors=24)[0].shape == (25, 25)


def test_n_eigen_not_below_the_point_count(patch_cloud) -> None:
    with pytest.raises(SpectralError, match=r"n_eigen=400 .* only 400 points.*e\.g\. 200"):
        build_basis(patch_cloud, n_eigen=400, cache=False)
    with pytest.raises(SpectralError, match="1 ≤ n_eigen < 400"):
        laplace_eigenpairs(*point_cloud_laplacian(patch_cloud.points), 400)


@pytest.mark.parametrize("bad", [0, -3, 2.5, True])
def test_bad_n_eigen(patch_cloud, bad) -> None:
    with pytest.raises(ConfigError, match="n_eigen"):
        build_basis(patch_cloud, n_eigen=bad, cache=False)


@pytest.mark.parametrize("bad", [2, 0, 7.0])
def test_bad_n_neighbors(bad) -> None:
    with pytest.raises(ConfigError, match="n_neighbors"):
        point_cloud_laplacian(curved_patch(10), n_neighbors=bad)


@pytest.mark.parametrize("bad", [-1e-5, np.nan])
def test_bad_mollify(bad) -> None:
    with pytest.raises(ConfigError, match="mollify"):
        point_cloud_laplacian(curved_patch(10), mollify_factor=bad)


def test_not_a_cloud() -> None:
    with pytest.raises(CloudError, match="SurfaceCloud"):
        build_basis(curved_patch(10), n_eigen=5, cache=False)  # type: ignore[arg-type]


@pytest.mark.parametrize(("alpha", "spacing"), [(-1.0, 0.003), (0.0, 0.003), (10.0, -0.003), (np.inf, 0.003)])
def test_bad_timestep(alpha: float, spacing: float) -> None:
    with pytest.raises(ConfigError, match=r"alpha|spacing"):
        diffusion_timestep(alpha, spacing)


def test_bad_dt_and_substeps(patch_basis) -> None:
    with pytest.raises(ConfigError, match="dt"):
        SpectralDiffusion(patch_basis, -1.0)
    with pytest.raises(ConfigError, match="dt"):
        ImplicitDiffusion(patch_basis.L, patch_basis.M, np.nan)
    with pytest.raises(ConfigError, match="substeps"):
        ImplicitDiffusion(patch_basis.L, patch_basis.M, 1e-4, substeps=0)
    with pytest.raises(InputError, match="must be square"):
        ImplicitDiffusion(patch_basis.L, patch_basis.mass[:-1], 1e-4)


def test_bad_field(patch_basis) -> None:
    step = SpectralDiffusion.from_alpha(patch_basis, 10.0)
    with pytest.raises(InputError, match=r"shape \(400,\)"):
        step(np.zeros(399))
    u = np.zeros(400)
    u[5] = np.nan
    with pytest.raises(InputError, match="NaN"):
        step(u)
    with pytest.raises(InputError, match="NaN"):
        ImplicitDiffusion(patch_basis.L, patch_basis.M, 1e-4)(u)


def test_zero_dt_is_identity_on_the_span(patch_basis, rng: np.random.Generator) -> None:
    c = rng.standard_normal(patch_basis.n_eigen)
    u = patch_basis.reconstruct(c)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(SpectralDiffusion(patch_basis, 0.0)(u), u, atol=1e-9 * np.abs(u).max())
    np.testing.assert_allclose(patch_basis.project(u), c, atol=1e-9)


def test_near_full_spectrum_on_large_clouds_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    L, M = point_cloud_laplacian(curved_patch(16))  # 256 points
    monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10)
    monkeypatch.setattr(exact_mod, "DENSE_LIMIT_POINTS", 100)
    with pytest.raises(SpectralError, match="n_eigen ≤ 128"):
        laplace_eigenpairs(L, M, 255)
    # Just below the limit ARPACK still runs, with as many Lanczos vectors as there are points.
    vals, _ = laplace_eigenpairs(L, M, 200)
    monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10_000)
    dense, _ = laplace_eigenpairs(L, M, 200)
    np.testing.assert_allclose(vals, dense, rtol=1e-7, atol=1e-7 * dense[-1])


def test_default_cache_dir_is_under_home(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    from tactex.spectral import default_cache_dir

    monkeypatch.delenv("TACTEX_CACHE_DIR", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    assert default_cache_dir() == tmp_path / ".cache" / "tactex" / "basis"


def test_solver_runs_without_threadpoolctl(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "threadpoolctl", None)  # import now raises ImportError
    exact_mod._blas_controller.cache_clear()  # the controller is looked up once per process
    try:
        L, M = point_cloud_laplacian(curved_patch(30))
        monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10)
        vals, vecs = laplace_eigenpairs(L, M, 8)
        assert exact_mod._blas_controller() is None
        assert vals.shape == (8,) and np.all(np.isfinite(vecs))
    finally:
        exact_mod._blas_controller.cache_clear()  # later tests find threadpoolctl again


def test_solver_pins_blas_to_one_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    threadpoolctl = pytest.importorskip("threadpoolctl")
    seen = []
    real_eigsh = exact_mod.sla.eigsh

    def spy(*args, **kwargs):
        seen.extend(info["num_threads"] for info in threadpoolctl.threadpool_info() if info["user_api"] == "blas")
        return real_eigsh(*args, **kwargs)

    monkeypatch.setattr(exact_mod.sla, "eigsh", spy)
    monkeypatch.setattr(exact_mod, "DENSE_MAX_POINTS", 10)
    L, M = point_cloud_laplacian(curved_patch(30))
    laplace_eigenpairs(L, M, 8)
    assert seen and all(n == 1 for n in seen)
