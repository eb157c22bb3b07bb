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


def test_the_tool_wrench_is_the_flange_reading_less_the_declared_load():
    """The robot's view of the tool's wrench on the environment (tactex.twin.wrench.tool_wrench_on_environment):
    a rigid load, accelerated, pressed on at a point, read at the flange, gives back the press; a load declared
    heavier than it is reads as the robot pushing down by the difference, as on a Franka."""
    import numpy as np

    from tactex.twin.wrench import tool_wrench_on_environment

    g = np.array([0.0, 0.0, -9.81])
    rng = np.random.default_rng(7)
    for _ in range(20):
        mass = rng.uniform(0.5, 3.0)
        flange, com, contact = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
        acc = rng.normal(size=3)  # the load's acceleration [m/s²]
        env_on_tool = rng.normal(scale=20.0, size=3)
        # the load's balance, a point mass: flange + environment + weight = m·a, and the moments about the origin
        flange_force = mass * (acc - g) - env_on_tool
        flange_moment_0 = np.cross(com, mass * (acc - g)) - np.cross(contact, env_on_tool)
        flange_moment = flange_moment_0 - np.cross(flange, flange_force)  # about the flange
        force, moment = tool_wrench_on_environment(tuple(flange_force), tuple(flange_moment), tuple(flange), mass,
                                                   tuple(com), tuple(acc - g))
        assert np.allclose(force, -env_on_tool, atol=1e-9)
        assert np.allclose(moment, np.cross(contact, -env_on_tool), atol=1e-9)
    # at rest, declared 0.5 kg heavier than it is: the model takes away 0.5 kg more weight than hangs there
    mass = 2.0
    force, moment = tool_wrench_on_environment((0.0, 0.0, mass * 9.81), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                                               mass + 0.5, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81))
    assert np.allclose(force, (0.0, 0.0, -0.5 * 9.81)) and np.allclose(moment, 0.0)
