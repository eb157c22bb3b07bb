"""The 3-D page of a big cloud: drawn through an even subset of its points (the target and the points the
path touched kept first), at most ~10 MB with every colouring a report offers, saying how many points it
shows; a small cloud drawn whole; the path lifted off the surface so that the markers do not hide it."""

from __future__ import annotations

import base64
import dataclasses
import re

import numpy as np
import pytest

from tactex.errors import ConfigError
from tactex.report.display_subset import display_subset, even_pick, touched_points
from tactex.report.html import KEEP_SHARE, PAGE_POINTS, cloud_html
from tactex.report.path_lift import LIFT_SHARE, lift_path

from .page_scene import AXES, CENTRES, people_scene

SHOWING = re.compile(r"showing ([0-9 ]+) of ([0-9 ]+) points")


def clean_like_fields(scene) -> dict[str, np.ndarray]:
    """Four colourings, as clean's page has (the most of any report): two dirt captures, coverage, potential."""
    rng = np.random.default_rng(3)
    n = len(scene.points)
    return {"dirt (first capture)": scene.target.astype(float), "dirt (last capture)": 0.5 * scene.target,
            "coverage": rng.uniform(size=n), "potential": rng.normal(size=n)}


def _arrays(page: str) -> list[np.ndarray]:
    return [np.frombuffer(base64.b64decode(b), dtype="<f4")
            for b in re.findall(r'"dtype":"f4","bdata":"([^"]+)"', page)]


@pytest.fixture(scope="module")
def scene():
    return people_scene()


def test_a_240k_point_page_is_at_most_10_mb_and_says_how_many_points_it_shows(tmp_path, scene) -> None:
    page = cloud_html(scene.points, clean_like_fields(scene), tmp_path / "big.html", trajectory=scene.path,
                      keep=scene.target, normals=scene.normals, title="five people")
    size_mb = page.stat().st_size / 1e6
    assert size_mb <= 10.0, f"{size_mb:.2f} MB"
    text = page.read_text()
    shown, total = (int(g.replace(" ", "")) for g in SHOWING.search(text).groups())
    assert total == len(scene.points) == 240_000 and 0.9 * PAGE_POINTS <= shown <= PAGE_POINTS
    # the positions once, each colouring once in the menu (the first also in the trace)
    assert sum(a.shape == (shown,) for a in _arrays(text)) == 3 + 4 + 1


def test_a_small_cloud_is_drawn_whole(tmp_path) -> None:
    small = people_scene(3000, path_steps=200)
    page = cloud_html(small.points, clean_like_fields(small), tmp_path / "small.html", trajectory=small.path,
                      include_plotlyjs="cdn").read_text()
    assert not SHOWING.search(page)
    drawn = _arrays(page)
    for axis in range(3):
        assert any(np.array_equal(a, small.points[:, axis].astype(np.float32)) for a in drawn)


def test_the_subset_keeps_every_target_and_path_point_is_even_and_deterministic(scene) -> None:
    touched = touched_points(scene.points, scene.path)
    wanted = scene.target | touched
    assert 0 < wanted.sum() <= KEEP_SHARE * PAGE_POINTS
    first = display_subset(scene.points, PAGE_POINTS, wanted, KEEP_SHARE)
    again = display_subset(scene.points, PAGE_POINTS, wanted, KEEP_SHARE)
    np.testing.assert_array_equal(first, again)
    assert np.all(np.diff(first) > 0) and 0.9 * PAGE_POINTS <= first.size <= PAGE_POINTS
    assert wanted[first].sum() == wanted.sum()  # every target point and every point the path touched
    # even: each person and each quarter of the floor keeps about the share of the points it had
    shown = np.zeros(len(scene.points), dtype=bool)
    shown[first] = True
    others = ~wanted
    floor = others & (scene.points[:, 2] < 0.05)
    for quarter in (floor & (scene.points[:, 0] < -1.5), floor & (scene.points[:, 0] > 1.5)):
        assert shown[quarter].sum() / quarter.sum() == pytest.approx(shown[others].sum() / others.sum(), rel=0.35)


def test_a_target_over_its_share_is_thinned_evenly_to_the_share(scene) -> None:
    """The share is the least a big target gets: the rest of the budget is spread over the whole cloud, the
    target's other points included, so the people still get points beside a floor marked whole."""
    budget = 20_000
    big_target = scene.points[:, 2] < 0.05  # the whole floor: 120 000 points
    kept = display_subset(scene.points, budget, big_target, 0.25)
    assert kept.size <= budget and big_target[kept].sum() >= 0.9 * 0.25 * budget
    people = np.linalg.norm((scene.points[kept][:, None, :] - CENTRES[None]) / AXES, axis=2) < 1.01
    assert (people.sum(axis=0) > 0.03 * budget).all()  # every person drawn
    np.testing.assert_array_equal(kept, display_subset(scene.points, budget, big_target, 0.25))
    # a share of 1 may take the whole budget
    assert big_target[display_subset(scene.points, budget, big_target, 1.0)].sum() >= 0.9 * budget


def test_even_pick_meets_its_budget() -> None:
    pts = np.random.default_rng(0).random((5000, 3))
    for budget in (1, 10, 777, 4999):
        pick = even_pick(pts, budget)
        assert pick.size <= budget and pick.size >= 0.9 * budget and len(np.unique(pick)) == pick.size
    assert even_pick(pts, 5000).size == 5000 and even_pick(np.zeros((9, 3)), 3).size == 1


@pytest.mark.parametrize("budget", [0, -5, 2.5, True, "100", None])
def test_a_bad_point_budget_is_a_config_error(tmp_path, budget) -> None:
    pts = np.random.default_rng(0).random((50, 3))
    with pytest.raises(ConfigError, match="point budget") as err:
        cloud_html(pts, None, tmp_path / "x.html", max_points=budget, include_plotlyjs=False)
    assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="point budget"):
        display_subset(pts, budget)


@pytest.mark.parametrize("share", [-0.1, 1.5, float("nan"), "half"])
def test_a_bad_keep_share_is_a_config_error(share) -> None:
    with pytest.raises(ConfigError, match=r"in \[0, 1\]") as err:
        display_subset(np.zeros((5, 3)), 3, None, share)
    assert "\n" not in str(err.value)


def test_the_path_is_lifted_along_the_normals_or_to_both_sides(scene) -> None:
    path = scene.path[::500]
    lift = LIFT_SHARE * np.linalg.norm(np.ptp(scene.points, axis=0))
    up = lift_path(path, scene.points, scene.normals)
    assert up.shape == path.shape
    np.testing.assert_allclose(np.linalg.norm(up - path, axis=1), lift, rtol=1e-9)
    on_floor = path[:, 2] < 0.05
    assert (up[on_floor, 2] > path[on_floor, 2]).all()  # the floor's normals point up: the path above it
    both = lift_path(path, scene.points, None)
    assert both.shape == (2 * len(path) + 1, 3) and np.isnan(both[len(path)]).all()
    np.testing.assert_allclose(both[: len(path)] - path, path - both[len(path) + 1:], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(both[: len(path)] - path, axis=1), lift, rtol=1e-9)
    broken = np.vstack([path[:3], np.full((1, 3), np.nan), path[3:6]])  # a NaN break stays a break
    assert np.isnan(lift_path(broken, scene.points, scene.normals)[3]).all()


def test_the_explore_help_states_the_page_budget() -> None:
    from tactex.experiments.explore import ExploreConfig

    help_text = next(f.metadata["help"] for f in dataclasses.fields(ExploreConfig) if f.name == "html")
    assert f"{PAGE_POINTS:,}".replace(",", " ") in help_text and "10 MB" in help_text
