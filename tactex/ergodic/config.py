"""Parameters of the HEDAC explorer, with TEC's values as defaults (Table II, §V-B, §VI-E)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from tactex.config import param
from tactex.errors import ConfigError

__all__ = ["HedacConfig"]


@dataclass(frozen=True)
class HedacConfig:
    """HEDAC spectral exploration on a point cloud.

    Lengths of the agent's motion are in units of the cloud spacing h (the voxel size, 3 mm in
    the paper), so Table II's 3 mm/s and 3 mm/s² at a 3 mm voxel and a 1 s step are
    ``max_velocity = 1`` voxel/step and ``max_acceleration = 1`` voxel/step². Table II's
    "M = 20" is the number of nearest neighbours n_N of the tangent-space fit and the gradient
    (the authors' code: ``nb_minimum_neighbors = 20``).
    """

    alpha: float = param(10.0, "diffusion scale α of δt = α h² (TEC eq. 21) [-]")
    alpha_final: float = param(
        0.0, "α at the end of the schedule (high α first, lower later, §VI-E); 0 = constant α [-]"
    )
    alpha_decay_steps: int = param(300, "steps over which α decays geometrically to alpha_final [steps]")
    n_eigen: int = param(200, "eigenpairs n_K of the spectral diffusion (eq. 19) [-]")
    agent_radius_m: float = param(0.0075, "agent footprint radius r_a (15 mm on the plate) [m]")
    footprint_sharpness: float = param(
        1.0, "ε·r_a of the Gaussian footprint φ(r) = exp(−ε² r²) (eq. 30); φ(r_a) = exp(−sharpness²) [-]"
    )
    n_neighbors_fit: int = param(20, "nearest neighbours n_N of the sphere/plane and cubic fits (Table II 'M') [-]")
    max_velocity: float = param(1.0, "speed limit ẋmax [voxels/step] (Table II: 3 mm/s at 3 mm, 1 s)")
    max_acceleration: float = param(1.0, "acceleration limit ẍmax [voxels/step²] (Table II: 3 mm/s²)")
    step_duration_s: float = param(1.0, "duration of one exploration step, converts voxels/step to m/s [s]")
    order: int = param(2, "agent dynamics: 1 (velocity along the gradient) or 2 (acceleration, eq. 6) [-]")
    source_in_potential: bool = param(True, "add the undiffused source to the potential at the neighbours")
    max_snap_distance: float = param(
        10.0, "farthest start/measured position from the cloud that is projected onto it [voxels]"
    )
    seed: int = param(0, "seed of the random heading used when the potential is exactly flat [-]")

    def __post_init__(self) -> None:
        positive = {
            "alpha": self.alpha,
            "agent_radius_m": self.agent_radius_m,
            "footprint_sharpness": self.footprint_sharpness,
            "max_velocity": self.max_velocity,
            "max_acceleration": self.max_acceleration,
            "step_duration_s": self.step_duration_s,
            "max_snap_distance": self.max_snap_distance,
        }
        for name, value in positive.items():
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"HedacConfig.{name} must be a positive finite number, got {value!r}")
        if not math.isfinite(self.alpha_final) or self.alpha_final < 0:
            raise ConfigError(f"HedacConfig.alpha_final must be ≥ 0 (0 = no schedule), got {self.alpha_final!r}")
        for name, low in (("n_eigen", 1), ("n_neighbors_fit", 5), ("alpha_decay_steps", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(f"HedacConfig.{name} must be an integer ≥ {low}, got {value!r}")
        if self.order not in (1, 2):
            raise ConfigError(f"HedacConfig.order must be 1 or 2, got {self.order!r}")
        if self.agent_radius_m > 1.0:
            raise ConfigError(
                f"HedacConfig.agent_radius_m = {self.agent_radius_m} m is larger than a robot workspace; "
                "it is in metres (e.g. 0.0075 for 7.5 mm)"
            )

    def alpha_at(self, step: int) -> float:
        """α of the schedule at ``step`` (constant when alpha_final = 0)."""
        if self.alpha_final <= 0 or step <= 0:
            return self.alpha
        frac = min(step / self.alpha_decay_steps, 1.0)
        return self.alpha * (self.alpha_final / self.alpha) ** frac
