"""The compiled walking step (tactex.ergodic.compiled_step) against the numpy step it replaces.

The numpy step is the reference. Each check runs two explorers side by side and, before every
step, copies the numpy explorer's whole state into the compiled one, so every step starts from the
same state: the two steps must agree to round-off, whatever the trajectory does later (HEDAC is
chaotic: 1e-14 differences grow into different paths after a few hundred steps).
"""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest

from tactex.ergodic import HedacConfig, HedacExplorer
from tactex.ergodic import compiled_step as cs
from tactex.errors import ConfigError
from tactex.experiments.explore import ExploreConfig, load_explore_cloud
from tactex.pointcloud import SurfaceCloud
from tactex.spectral import build_basis

from .conftest import gap_strips

needs_numba = pytest.mark.skipif(
    not cs.available(), reason="numba (the 'fast' extra) is not installed: the compiled step is not used"
)
POS_TOL = 1e-12  # [m] on positions of ~0.1 m: round-off of a different summation order
REL_TOL = 1e-10  # potential coefficients and velocities, relative to their largest entry
NRM_TOL = 1e-9  # unit normals and tangents: the fit far from a rim or with few points is less well conditioned


@pytest.fixture(scope="module")
def objects():
    out = {}
    for name in ("bowl", "cup", "plate"):
        cloud, _ = load_explore_cloud(name, ExploreConfig(voxel_size_m=0.004))
        out[name] = (cloud, build_basis(cloud, n_eigen=60, cache=False))
    return out


def _sync(dst: HedacExplorer, src: HedacExplorer) -> None:
    """dst takes src's whole dynamic state (positions, agents, coverage, potential, hops, rng)."""
    dst._x = src._x.copy()
    dst._nrm_t = list(src._nrm_t)
    dst._near = src._near.copy()
    dst._cov = src._cov.copy()
    dst._cov_sum = src._cov_sum
    dst._coef = src._coef.copy()
    dst._s_ext[:] = src._s_ext  # in place: _s_t is a view of it
    dst.path_lengths = src.path_lengths.copy()
    dst._bridges = copy.deepcopy(src._bridges)
    dst._rng = copy.deepcopy(src._rng)
    dst.step_count = src.step_count
    dst.bridges_taken = src.bridges_taken
    for a, b in zip(dst._agents, src._agents, strict=True):
        a.velocity = b.velocity.copy()


def _assert_same_step(cmds_c, cmds_n, ex_c: HedacExplorer, ex_n: HedacExplorer, k: int,
                      pos_tol: float = POS_TOL, nrm_tol: float = NRM_TOL) -> None:
    for c, n in zip(cmds_c, cmds_n, strict=True):
        # dt = 1 s here: a position tolerance [m] is the same number in velocity [m/s]
        # (and at least POS_TOL: an agent braked to a stop has velocities of ~1e-17 m/s)
        v_tol = max(REL_TOL * float(np.abs(n.velocity).max()), pos_tol)
        np.testing.assert_allclose(c.point, n.point, rtol=0, atol=pos_tol, err_msg=f"step {k}")
        np.testing.assert_allclose(c.velocity, n.velocity, rtol=0, atol=v_tol, err_msg=f"step {k}")
        for field in ("normal", "tangent_u", "tangent_v"):
            np.testing.assert_allclose(getattr(c, field), getattr(n, field), rtol=0, atol=nrm_tol, err_msg=field)
        assert (c.step, c.agent) == (n.step, n.agent)
    np.testing.assert_allclose(ex_c.coverage, ex_n.coverage, rtol=1e-12, atol=1e-15)
    assert ex_c._cov_sum == pytest.approx(ex_n._cov_sum, rel=1e-13)
    np.testing.assert_allclose(ex_c._s_ext, ex_n._s_ext, rtol=0, atol=REL_TOL * float(ex_n._s_ext.max() + 1e-300))
    scale = float(np.abs(ex_n._coef).max())
    np.testing.assert_allclose(ex_c._coef, ex_n._coef, rtol=0, atol=REL_TOL * scale, err_msg=f"step {k}")
    np.testing.assert_allclose(ex_c.path_lengths, ex_n.path_lengths, rtol=0, atol=pos_tol)
    np.testing.assert_array_equal(ex_c._near, ex_n._near)
    for a, b in zip(ex_c._agents, ex_n._agents, strict=True):
        # the tangential part of the step's velocity: it inherits the normals' tolerance (NRM_TOL)
        v_tol = max(REL_TOL, nrm_tol) * float(np.abs(b.velocity).max()) + pos_tol
        np.testing.assert_allclose(a.velocity, b.velocity, rtol=0, atol=v_tol)


def _run_side_by_side(cloud, basis, x0, steps: int, measured_noise_m: float = 0.0, pos_tol: float = POS_TOL,
                     nrm_tol: float = NRM_TOL, measured_offset_m: np.ndarray | None = None, **cfg) -> HedacExplorer:
    ex_c = HedacExplorer(cloud, basis, HedacConfig(n_eigen=basis.evecs.shape[1], **cfg))
    ex_n = ex_c.with_config(compiled=False)
    assert ex_c._walk_compiled is not None and ex_n._walk_compiled is None
    ex_c.reset(x0)
    ex_n.reset(x0)
    rng = np.random.default_rng(7)
    for k in range(steps):
        _sync(ex_c, ex_n)
        measured = None
        if measured_noise_m > 0.0:
            measured = ex_n.positions + rng.normal(scale=measured_noise_m, size=ex_n.positions.shape)
        if measured_offset_m is not None and k % 10 == 5:
            measured = ex_n.positions + measured_offset_m
        cmds_c = ex_c.step_all(measured)
        cmds_n = ex_n.step_all(measured)
        _assert_same_step(cmds_c, cmds_n, ex_c, ex_n, k, pos_tol, nrm_tol)
    return ex_c


def _start(cloud, frac: float = 0.3) -> np.ndarray:
    """A cloud point a fraction of the way across the cloud's bounding box (reproducible)."""
    lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
    return cloud.points[np.argmin(np.linalg.norm(cloud.points - (lo + frac * (hi - lo)), axis=1))]


@needs_numba
@pytest.mark.parametrize(
    "name, cfg",
    [
        ("bowl", {}),  # sphere fits, second-order agent
        ("cup", {"order": 1, "agent_radius_m": 0.006}),  # a vertical wall and its rim, first order
        ("plate", {"agent_radius_m": 0.015, "coverage_normalization": "domain"}),  # plane fits, eq. 2 literally
        ("bowl", {"source_weight": 0.0, "alpha": 3.0}),  # diffused potential only
        ("plate", {"agent_radius_m": 0.015, "cooling": 0.05}),  # eq. 4's heat loss
        # 10 neighbours for the fits' 5 and 10 unknowns: ill-conditioned, the two summation orders
        # (and LAPACK's dsyev vs numba's dsyevd for the 5 × 5 eigenproblem) differ by up to ~1e-7 m
        # in a step; a logic error moves the agent by millimetres.
        ("cup", {"n_neighbors_fit": 10, "pos_tol": 1e-6, "nrm_tol": 1e-5}),
    ],
)
def test_compiled_step_equals_the_numpy_step(objects, name, cfg):
    cloud, basis = objects[name]
    ex = _run_side_by_side(cloud, basis, _start(cloud), steps=150, **cfg)
    # The comparison means something only if the compiled step did take the steps.
    assert ex.compiled_steps >= 0.9 * 150


@needs_numba
def test_compiled_step_with_measured_positions(objects):
    cloud, basis = objects["bowl"]
    ex = _run_side_by_side(cloud, basis, _start(cloud, 0.3)[None, :], steps=80, measured_noise_m=0.0005)
    assert ex.compiled_steps >= 0.9 * 80


@needs_numba
def test_several_agents_run_the_numpy_step(objects):
    """Several agents lay their footprints before one diffusion (step_all); the compiled step walks
    one agent at a time, so it is not used, and both explorers take the same steps."""
    cloud, basis = objects["bowl"]
    x0 = np.stack([_start(cloud, 0.3), _start(cloud, 0.7)])
    ex = _run_side_by_side(cloud, basis, x0, steps=40, measured_noise_m=0.0005)
    assert ex.compiled_steps == 0


@needs_numba
def test_measured_positions_beyond_the_cloud_edge_are_pulled_back_alike(objects):
    # 4 voxels off the plate's rim: the landing slides, is clamped back within max_off_cloud_voxels, the
    # step is shortened and, when halving cannot get back, goes halfway to the nearest point.
    cloud, basis = objects["plate"]
    rim = cloud.points[np.argmax(cloud.points[:, 0])]
    # The 20 nearest points all lie to one side of such a position: the fit is less well conditioned.
    ex = _run_side_by_side(cloud, basis, rim, steps=60, measured_offset_m=np.array([0.016, 0.0, 0.0]),
                           pos_tol=1e-9, nrm_tol=1e-7, agent_radius_m=0.015)
    assert ex.compiled_steps >= 0.9 * 60


@needs_numba
@pytest.mark.parametrize("edge_braking", [True, False])
def test_braking_at_a_scan_edge_is_the_same_compiled(edge_braking):
    # a second-order agent running at the far edge of a flat grid, where its target strip lies
    h = 0.003
    u, v = np.meshgrid(np.arange(30) * h, np.arange(30) * h)
    pts = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    pts += np.random.default_rng(0).uniform(-2e-4, 2e-4, pts.shape) * [1, 1, 0]
    cloud = SurfaceCloud(pts, target=(pts[:, 0] > pts[:, 0].max() - 0.004).astype(float), spacing=h)
    basis = build_basis(cloud, n_eigen=60, cache=False)
    ex = _run_side_by_side(cloud, basis, pts[np.argmin(np.linalg.norm(pts - [0.01, 0.045, 0.0], axis=1))], steps=200,
                           edge_braking=edge_braking)
    assert ex.compiled_steps >= 0.9 * 200


@needs_numba
def test_unsynced_runs_follow_the_same_path_until_round_off_grows(objects):
    cloud, basis = objects["bowl"]
    ex_c = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    ex_n = ex_c.with_config(compiled=False)
    ex_c.reset(_start(cloud))
    ex_n.reset(_start(cloud))
    for _ in range(30):  # HEDAC is chaotic, but 30 steps keep 1e-14 differences far below 1 nm
        ex_c.step()
        ex_n.step()
    np.testing.assert_allclose(ex_c.positions, ex_n.positions, rtol=0, atol=1e-10)
    np.testing.assert_allclose(ex_c.coverage, ex_n.coverage, rtol=1e-9, atol=1e-12)
    assert ex_c.path_length == pytest.approx(ex_n.path_length, abs=1e-10)
    assert ex_c.compiled_steps >= 27


@needs_numba
def test_scan_hole_hops_go_through_numpy_and_agree():
    cloud = gap_strips(0.012, 0.01, seed=3)
    basis = build_basis(cloud, n_eigen=40, n_neighbors=30, cache=False)
    ex = _run_side_by_side(cloud, basis, cloud.points[20], steps=150, max_bridge_voxels=6.0)
    assert ex.bridges_taken >= 1, "the scenario must make the agent hop"
    assert 0 < ex.compiled_steps < 150  # the hops ran in numpy, the walk compiled


def _step_state(pts: np.ndarray, k: int = 8, seed: int = 0) -> dict:
    """Arguments of the compiled step on a bare cloud, every point a target point."""
    rng = np.random.default_rng(seed)
    n = len(pts)
    pts = pts.copy()
    phi = rng.normal(size=(n, k))
    for a in (pts, phi):  # read-only as in the explorer: the same compiled signature
        a.setflags(write=False)
    return dict(
        pts=pts, cand=np.arange(n, dtype=np.int64), x=pts[0].copy(), nrm=np.array([0.0, 0.0, 1.0]),
        vel=np.zeros(3), cov=rng.uniform(0.0, 1.0, n), cov_sum=1.0, tidx=np.arange(n, dtype=np.int64),
        tpos=np.arange(n, dtype=np.int64), p_t=np.full(n, 1.0 / n), phitm_t=rng.normal(size=(n, k)),
        coef=rng.normal(size=k), s_ext=rng.uniform(0.0, 1.0, n + 1), decay=np.full(k, 0.9), phi=phi,
        has=np.zeros(n, dtype=bool), n_n=8,
        prm=cs.params(agent_radius_m=0.0075, eps2=(1 / 0.0075) ** 2, source_weight=1.0, max_acceleration=0.003,
                       max_velocity=0.003, max_step_m=0.003, dt=1.0, max_off_m=0.003, edge_offset=0.25,
                       normalize_by_target=True, order=2),
        out=np.zeros(cs.OUT_SIZE), c_used=np.zeros(n), active=np.zeros(n, dtype=np.uint8), sums=np.zeros((3, k)),
        dcoef=np.zeros(k),
    )


def _grid(n_side: int = 9) -> np.ndarray:
    u, v = np.meshgrid(np.arange(n_side) * 0.003, np.arange(n_side) * 0.003)
    rng = np.random.default_rng(1)
    return np.c_[u.ravel(), v.ravel(), np.zeros(u.size)] + rng.uniform(-1e-4, 1e-4, (u.size, 3)) * [1, 1, 0]


@needs_numba
@pytest.mark.parametrize("case", ["degenerate", "edge_gap", "flat"])
def test_a_case_left_to_numpy_changes_no_state(case):
    pts = _grid()
    st = _step_state(pts)
    expected = cs.FLAT
    if case == "degenerate":  # collinear points: the numpy fit's line patch
        st = _step_state(np.c_[np.arange(12) * 0.003, np.zeros(12), np.zeros(12)])
        expected = cs.DEGENERATE
    elif case == "edge_gap":  # a corner of the grid, every point linked across a hole
        st["has"][:] = True
        expected = cs.EDGE_GAP
    else:  # no potential anywhere (Φ = 0) and no source left (p = 0): the gradient vanishes
        st["phi"] = np.zeros_like(st["phi"])
        st["phi"].setflags(write=False)
        st["p_t"][:] = 0.0
    before = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in st.items()}
    status = cs.compiled_walk_step()(*st.values())
    assert status == expected
    for key in ("cov", "coef", "s_ext", "x", "vel", "nrm"):
        np.testing.assert_array_equal(st[key], before[key], err_msg=key)


@needs_numba
def test_the_fits_tolerances_come_from_the_parameters_not_the_compiled_code():
    # numba would keep constants imported from fit.py in its cache after fit.py changed
    st = _step_state(_grid())
    assert cs.compiled_walk_step()(*st.values()) == cs.OK  # a regular grid: a plane
    st = _step_state(_grid())
    st["prm"][cs._DEGENERACY] = 1.0  # every neighbourhood counts as degenerate
    assert cs.compiled_walk_step()(*st.values()) == cs.DEGENERATE


@needs_numba
def test_a_compiled_step_that_fails_to_build_falls_back_to_numpy_with_a_warning(objects, monkeypatch):
    def broken():
        raise RuntimeError("no compiler here")

    real = cs.compiled_walk_step
    monkeypatch.setattr(cs, "_failure", None)  # restored after the test: later tests compile again
    monkeypatch.setattr(cs, "compiled_walk_step", broken)
    cloud, basis = objects["bowl"]
    with pytest.warns(RuntimeWarning, match="compiled exploration step is unavailable.*no compiler here"):
        ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    ex.reset(_start(cloud))
    for _ in range(5):
        ex.step()
    assert ex.compiled_steps == 0 and ex.path_length > 0
    # The failure is remembered: the next explorer does not try again, and says why.
    monkeypatch.setattr(cs, "compiled_walk_step", real)
    with pytest.warns(RuntimeWarning, match="no compiler here"):
        again = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    assert not again.compiled


@needs_numba
def test_a_compiled_step_that_fails_mid_run_hands_over_to_numpy(objects):
    cloud, basis = objects["bowl"]
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    ex.reset(_start(cloud))
    ex.step()
    assert ex.compiled_steps == 1

    def broken(*args):
        raise TypeError("no matching definition")

    ex._walk_compiled = broken
    with pytest.warns(RuntimeWarning, match="runs numpy from now on.*no matching definition"):
        ex.step()
    for _ in range(3):
        ex.step()
    assert not ex.compiled and ex.compiled_steps == 1 and np.isfinite(ex.positions).all()


def test_without_numba_or_when_switched_off_the_numpy_step_runs(objects, monkeypatch):
    cloud, basis = objects["bowl"]
    off = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, compiled=False))
    monkeypatch.setattr(cs, "available", lambda: False)
    missing = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    for ex in (off, missing):
        ex.reset(_start(cloud))
        for _ in range(5):
            ex.step()
        assert ex._walk_compiled is None and ex.compiled_steps == 0 and ex.path_length > 0


@needs_numba
def test_numba_with_its_jit_disabled_is_not_used(objects, monkeypatch):
    import numba

    monkeypatch.setattr(numba.config, "DISABLE_JIT", True)
    # restored after the test: the compiled step, its helpers and the failure flag
    for name in ("_compiled", "_failure", *cs.HELPERS):
        monkeypatch.setattr(cs, name, getattr(cs, name))
    cs._compiled = None
    cloud, basis = objects["bowl"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # quietly numpy: nothing failed
        ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60))
    assert not ex.compiled and cs._failure is None


@pytest.mark.parametrize("value", [1, "yes", None])
def test_compiled_must_be_a_bool(value):
    with pytest.raises(ConfigError, match=r"HedacConfig\.compiled"):
        HedacConfig(compiled=value)


@needs_numba
def test_the_small_sphere_check_decides_as_the_numpy_fit(rng):
    """The compiled step's test of a small sphere against the neighbourhood's PCA plane gives numpy's
    verdict (fit._sphere_beats_plane) on noisy spheres, one-sided caps, flat patches and the ragged
    bowl edge of test_fit."""
    from tactex.geometry import fit as fit_mod

    from .test_fit import RAGGED_EDGE_MM

    cs.compiled_walk_step()  # compiles the helpers in place
    cases = [RAGGED_EDGE_MM * 1e-3]
    for _ in range(300):
        centre = rng.normal(size=3)
        u = rng.normal(size=(20, 3)) + np.array([0.0, 0.0, rng.uniform(0.0, 3.0)])  # caps of varying extent
        pts = centre + 0.8 * u / np.linalg.norm(u, axis=1, keepdims=True)
        cases.append((pts + rng.normal(size=pts.shape) * rng.uniform(0.0, 0.1)) * 0.004)
    verdicts = []
    for d in cases:
        dd = (d * d).sum(axis=1)
        inv = 1.0 / np.sqrt(dd.max())
        q = d * inv
        w = np.c_[q, -np.ones(len(q)), -0.5 * (q * q).sum(axis=1)]
        for c, r in ((rng.normal(size=3), rng.uniform(0.3, 3.0)),):
            want = fit_mod._sphere_beats_plane(w, *c, r)
            got = cs._sphere_beats_plane(d, np.arange(len(d)), len(d), inv, *c, r)
            assert got == want, (d, c, r)
            verdicts.append(want)
        F = fit_mod.fit_local(q)  # the algebraic sphere itself, where the fit gave one
        if F.kind == "sphere":
            want = fit_mod._sphere_beats_plane(w, *F.center, F.radius)
            assert cs._sphere_beats_plane(d, np.arange(len(d)), len(d), inv, *F.center, F.radius) == want
            verdicts.append(want)
    assert 0.05 < np.mean(verdicts) < 0.95  # both verdicts occur


@pytest.mark.parametrize("compiled", [False, True])
def test_the_command_frame_is_orthonormal_at_its_point(objects, compiled):
    """(tangent_u, tangent_v, normal) of a command are orthonormal at the command's point and its
    velocity is tangent (the tangent basis was the one before the move, up to 31° off the normal on
    the bunny, and the velocity the chord)."""
    if compiled and not cs.available():
        pytest.skip("numba (the 'fast' extra) is not installed")
    cloud, basis = objects["bowl"]
    ex = HedacExplorer(cloud, basis, HedacConfig(n_eigen=60, compiled=compiled))
    ex.reset(_start(cloud))
    for _ in range(150):
        c = ex.step()
        frame = np.stack([c.tangent_u, c.tangent_v, c.normal])
        np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(frame) > 0.0
        assert abs(float(c.velocity @ c.normal)) <= 1e-12 * max(1.0, float(np.linalg.norm(c.velocity)))
    assert (ex.compiled_steps > 100) == compiled


@needs_numba
def test_compile_pending_says_whether_a_compile_or_cache_load_is_ahead(objects, monkeypatch):
    cloud, basis = objects["plate"]
    ex = HedacExplorer(cloud, basis, HedacConfig(agent_radius_m=0.015, n_eigen=basis.evecs.shape[1]))
    ex.reset(_start(cloud))
    ex.step()
    assert ex.compiled_steps == 1 and not cs.compile_pending()  # machine code in hand
    monkeypatch.setattr(cs, "_compiled", None)
    assert cs.compile_pending()  # a fresh process: numba will compile or load its cache
    from numba import config

    monkeypatch.setattr(config, "DISABLE_JIT", True)
    assert not cs.compile_pending()  # the step would run numpy: nothing to wait for
    monkeypatch.setattr(config, "DISABLE_JIT", False)
    monkeypatch.setattr(cs, "_failure", "broken")
    assert not cs.compile_pending()


def test_the_former_module_name_is_the_compiled_step_itself():
    """``tactex.ergodic.kernel`` is the same module object: attributes set through it reach the step."""
    from tactex.ergodic import kernel

    assert kernel is cs
