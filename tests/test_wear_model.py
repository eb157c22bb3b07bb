"""The robot's own Preston wear model (issue 21): predicted removal on the captured cloud."""

from __future__ import annotations

import numpy as np
import pytest

from tactex.errors import ConfigError, InputError
from tactex.pointcloud.cloud import SurfaceCloud
from tactex.tasks.wear_model import WearModel

K_P, R, F = 5e-3, 0.025, 10.0


def _plane(spacing: float = 0.002, half: float = 0.06) -> SurfaceCloud:
    g = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    return SurfaceCloud(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)), target=np.ones(len(pts)),
                        spacing=spacing)


def test_one_straight_pass_removes_prestons_chord_integral() -> None:
    """A pad sliding along x at force F removes k_p·F/(π r²) per metre the point spends under the disc:
    at a lateral offset d that is the chord 2·sqrt(r² − d²)."""
    cloud = _plane()
    wear = WearModel(cloud, K_P, R)
    step = 0.0005
    for x in np.arange(-0.06, 0.06 + 1e-9, step):  # ∫F·v dt over one step = F · step
        wear.wipe(np.array([x, 0.0, 0.0]), F * step)
    on_line = (np.abs(cloud.points[:, 0]) < 0.02)
    for d in (0.0, 0.01, 0.02):
        pts = on_line & np.isclose(cloud.points[:, 1], d)
        expected = K_P * F / (np.pi * R**2) * 2.0 * np.sqrt(R**2 - d**2)
        np.testing.assert_allclose(wear.removed[pts], expected, rtol=0.03)
    assert np.all(wear.removed[np.abs(cloud.points[:, 1]) > R + 1e-9] == 0.0)  # outside the band: untouched


def test_remaining_margin_reset_and_fraction() -> None:
    cloud = _plane()
    wear = WearModel(cloud, K_P, R, margin=2.0)
    removal = K_P * F * 0.01 / (np.pi * R**2)  # one update of ∫F·v dt = 0.1 N·m
    wear.wipe(np.zeros(3), F * 0.01)
    under = np.linalg.norm(cloud.points, axis=1) <= R
    np.testing.assert_allclose(wear.remaining()[under], 1.0 - removal / 2.0)  # the margin halves the credit
    assert np.all(wear.remaining()[~under] == 1.0)
    assert wear.remaining_fraction(cloud.target.sum()) == pytest.approx(1.0 - under.mean() * removal / 2.0)
    wear.wipe(np.zeros(3), 0.0)  # no force or no slip: nothing
    wear.wipe(np.zeros(3), -1.0)
    np.testing.assert_allclose(wear.remaining()[under], 1.0 - removal / 2.0)
    new = np.where(cloud.points[:, 0] > 0, 1.0, 0.0)
    wear.reset(new)  # a camera view replaces the prediction
    np.testing.assert_array_equal(wear.remaining(), new)
    with pytest.raises(InputError, match="shape"):
        wear.reset(np.ones(3))


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"preston_coefficient": 0.0}, "preston_coefficient"), ({"pad_radius_m": float("nan")}, "pad_radius_m"),
    ({"force_threshold_n": -1.0}, "force_threshold_n"), ({"margin": 0.0}, "margin")])
def test_wear_model_validation(kwargs, match) -> None:
    args = {"preston_coefficient": K_P, "pad_radius_m": R, **kwargs}
    with pytest.raises(ConfigError, match=match):
        WearModel(_plane(), **args)


def test_islands_left_and_the_next_one() -> None:
    """Two islands of dirt on a plane: after one is wiped, the next touch-down is the other one's nearest
    point, and an island already tried since the last view is not offered again."""
    cloud = _plane()
    x = cloud.points[:, 0]
    target = ((np.abs(x + 0.05) < 0.006) | (np.abs(x - 0.05) < 0.006)).astype(float)
    wear = WearModel(cloud, K_P, R)
    wear.reset(target)
    left_island = np.array([-0.05, 0.0, 0.0])
    assert wear.island_left(left_island, 2 * R)
    assert wear.dirty().sum() == target.sum()
    for y in np.arange(-0.09, 0.09 + 1e-9, 0.0005):  # wipe the left strip along its length, and past its ends
        wear.wipe(np.array([-0.05, y, 0.0]), F * 0.0005)
    assert not wear.island_left(left_island, 0.02)  # every point there had its pass (removal ≥ 1)
    nxt = wear.next_island(left_island, [], 0.02)
    assert nxt is not None and abs(nxt[0] - 0.044) < 0.003 and abs(nxt[1]) < 0.003  # the right strip's nearest
    assert wear.next_island(left_island, [nxt], 0.07) is None  # tried (all of it within 7 cm): the camera judges
    assert wear.dirt_near(nxt, 0.01) == pytest.approx(target[np.linalg.norm(cloud.points - nxt, axis=1) <= 0.01].sum())
    assert wear.dirt_near(left_island, 0.01) == 0.0
    assert wear.dirty_fraction(target.sum()) == pytest.approx(0.5, abs=0.02)  # the right strip is left


def test_the_next_island_touches_down_only_where_allowed() -> None:
    """An island move's touch-down keeps clear of a keep-out zone as the agent does: the nearest dirty point it may
    touch down on, not the nearest dirty point (which lies at the zone's edge)."""
    cloud = _plane()
    x = cloud.points[:, 0]
    target = (np.abs(x - 0.03) < 0.02).astype(float)  # dirt from x = 10 to 50 mm
    wear = WearModel(cloud, K_P, R)
    wear.reset(target)
    here = np.array([-0.05, 0.0, 0.0])
    assert wear.next_island(here, [], 0.02)[0] < 0.012  # the dirt's near edge
    allowed = x >= 0.025  # e.g. a keep-out strip at x <= 10 mm and a 15 mm footprint
    nxt = wear.next_island(here, [], 0.02, allowed)
    assert nxt is not None and 0.025 <= nxt[0] < 0.028 and abs(nxt[1]) < 0.003
    assert wear.next_island(here, [], 0.02, np.zeros(len(x), dtype=bool)) is None
    with pytest.raises(InputError, match="allowed"):
        wear.next_island(here, [], 0.02, allowed[:-1])
