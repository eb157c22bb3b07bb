"""The twin's contact wrench in libfranka's frames (tactex.twin.wrench.wrench_about_k), without franky-sim."""

from __future__ import annotations


def test_wrench_about_k_matches_the_matrix_form():
    """The twin's float form of libfranka's O_F_ext_hat_K / K_F_ext_hat_K against the numpy form."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from tactex.twin.wrench import wrench_about_k

    def pose(rng):
        t = np.eye(4)
        t[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        t[:3, 3] = rng.normal(size=3)
        return t

    rng = np.random.default_rng(3)
    for ee_t_k in (np.eye(4), pose(rng)):
        o_t_ee = pose(rng)
        f, m0 = rng.normal(size=3), rng.normal(size=3)
        o_t_k = o_t_ee @ ee_t_k
        p, rot = o_t_k[:3, 3], o_t_k[:3, :3]
        world_ref = -np.r_[f, m0 - np.cross(p, f)]
        k_ref = np.r_[rot.T @ world_ref[:3], rot.T @ world_ref[3:]]
        world, k = wrench_about_k(tuple(o_t_ee.flatten(order="F")), tuple(ee_t_k.flatten(order="F")),
                                  tuple(f), tuple(m0), -1.0)
        assert np.allclose(world, world_ref, atol=1e-12) and np.allclose(k, k_ref, atol=1e-12)
