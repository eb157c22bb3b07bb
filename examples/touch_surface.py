"""Touch the VA-UFIC sine panel: approach, press with 15 N, wipe 10 cm along the curvature.

Runs the MuJoCo scene (Franka + F/T sensor + sponge + wrist camera) with a simple Cartesian
impedance and a force feed-forward, prints the contact force and the dirt removed, and writes
``touch_surface.png`` (wrist depth/colour, force trace, dirt map) and, when OpenGL works
(``MUJOCO_GL=egl``), ``touch_surface_gl.png`` (a rendered view of the scene).

    python examples/touch_surface.py --out runs/touch
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

os.environ.setdefault("MPLBACKEND", "Agg")

from tactex.errors import MissingDependencyError
from tactex.pointcloud.shapes import sine_panel_height
from tactex.robots import MujocoBackend
from tactex.sim import SceneConfig
from tactex.sim.testing import SimpleImpedance

DOWN = np.diag([1.0, -1.0, -1.0])  # tool z down, tool x along world x
FORCE_N = 15.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/touch_surface", help="output folder")
    parser.add_argument("--seconds", type=float, default=6.0, help="duration of the run [s]")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    backend = MujocoBackend(SceneConfig(object_name="sine_panel", marking="full", camera_width=160, camera_height=120))
    pos, _ = backend.object_pose()
    y0 = 0.05
    surface_z = float(sine_panel_height(np.array(0.0), np.array(y0)))
    hover = pos + np.array([0.0, y0, surface_z + 0.03])
    backend.reset(seed=0, q0=backend.solve_ik(hover, DOWN))
    first_frame = backend.render_depth()

    ctrl = SimpleImpedance(free_axes=(2,))
    log = []
    n = int(args.seconds / backend.dt)
    for _ in range(n):
        s = backend.state()
        t = s.t
        # 1 s descent under the force feed-forward, then slide 10 cm along −y over the sine
        y = y0 - 0.1 * np.clip((t - 1.5) / (args.seconds - 2.0), 0.0, 1.0)
        target = pos + np.array([0.0, y, 0.0])
        ff = np.array([0.0, 0.0, -FORCE_N * min(1.0, t / 0.5), 0.0, 0.0, 0.0])
        backend.apply_torque(ctrl.torque(s, target, DOWN, ff))
        backend.step()
        log.append((t, s.wrench_tool[2], backend.pad_contact()[0], s.ee_position[1], s.ee_position[2]))
    log = np.array(log)
    contact = log[log[:, 0] > 1.5]
    print(f"contact force over the wipe: mean {contact[:, 1].mean():.2f} N (F/T), "
          f"ground truth {contact[:, 2].mean():.2f} N, set point {FORCE_N:.0f} N")
    print(f"dirt remaining on the panel: {100 * backend.dirt_remaining():.1f} %")
    frame = backend.render_depth()

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 3, figsize=(14, 8))
    for col, (f, title) in enumerate(((first_frame, "before"), (frame, "after"))):
        im = ax[0, col].imshow(np.where(f.depth_m > 0, f.depth_m, np.nan), cmap="viridis")
        ax[0, col].set_title(f"wrist depth {title} [m]")
        fig.colorbar(im, ax=ax[0, col])
        ax[1, col].imshow(f.rgb)
        ax[1, col].set_title(f"wrist colour {title} (red = dirt)")
    ax[0, 2].plot(log[:, 0], log[:, 1], label="F/T f_z (tool)")
    ax[0, 2].plot(log[:, 0], log[:, 2], "--", label="contact (ground truth)")
    ax[0, 2].axhline(FORCE_N, color="k", lw=0.5)
    ax[0, 2].set_xlabel("t [s]")
    ax[0, 2].set_ylabel("force [N]")
    ax[0, 2].legend()
    ax[1, 2].imshow(backend.dirt.level_image(), origin="lower", cmap="Reds", vmin=0, vmax=1,
                    extent=(-0.13, 0.13, -0.255, 0.255))
    ax[1, 2].set_title("dirt on the panel (object frame x, y [m])")
    fig.tight_layout()
    fig.savefig(out / "touch_surface.png", dpi=100)
    print(f"written: {out / 'touch_surface.png'}")
    try:
        import matplotlib.image

        matplotlib.image.imsave(out / "touch_surface_gl.png", backend.render_rgb(640, 480, camera="overview"))
        print(f"written: {out / 'touch_surface_gl.png'}")
    except MissingDependencyError as exc:
        print(f"no GL image: {exc}")
    backend.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
