"""A hand-eye calibration file (tool_T_camera) is refused saying what is wrong with it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactex.errors import InputError
from tactex.tasks.hand_eye import load_hand_eye


def _pose() -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = [0.05, 0.0, 0.02]
    return pose


@pytest.mark.parametrize(("change", "says"), [
    (lambda p: p[:3], r"got shape \(3, 4\)"),
    (lambda p: p * np.where(np.eye(4) == 1, 2.0, 1.0), r"no rotation \(Rᵀ·R is not the identity: a scale"),
    (lambda p: np.where(np.isclose(p, 0.05), np.nan, p), "it holds NaN or inf"),
    (lambda p: np.vstack([p[:3], [0.0, 0.0, 0.1, 1.0]]), r"its last row is \[0.0, 0.0, 0.1, 1.0\]"),
    (lambda p: p @ np.diag([1.0, 1.0, -1.0, 1.0]), r"a reflection \(determinant −1\)"),
    (lambda p: np.hstack([p[:, :3], [[120.0], [0.0], [35.0], [1.0]]]), "sits 120 m from the tool, farther than 1 m"),
])
def test_a_bad_hand_eye_file_says_what_is_wrong(tmp_path, change, says) -> None:
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(np.asarray(change(_pose())).tolist()))
    with pytest.raises(InputError, match=says):
        load_hand_eye(path)
    np.save(tmp_path / "ok.npy", _pose())
    np.testing.assert_array_equal(load_hand_eye(tmp_path / "ok.npy"), _pose())
