"""How many eigenpairs n_K a surface needs, from its area and the agent's footprint.

The K-th Laplace eigenfunction of a surface of area A varies on the length √(πA/K) (Weyl's law,
λ_K ≈ 4πK/A), so a basis resolves the agent's footprint once K grows with A/(π r_a²), the number of
footprints the surface holds. On the built-in door, with far fewer modes than that the agent stalls
and part of the target is never covered, while more than about one mode per five footprints adds
nothing to coverage or ergodicity (the runs are tabulated in ``docs/large_surfaces.md``). Hence one
mode per ``FOOTPRINTS_PER_MODE`` footprints, never fewer than TEC's 200 (which small objects keep).
"""

from __future__ import annotations

import math

from tactex.errors import ConfigError

__all__ = ["FOOTPRINTS_PER_MODE", "MAX_AUTO_EIGEN", "MIN_AUTO_EIGEN", "auto_n_eigen"]

#: Footprint areas π r_a² of surface per eigenpair (from the door runs, see the module doc).
FOOTPRINTS_PER_MODE = 5.0
#: TEC's n_K (Fig. 11), the floor of the rule: small objects keep the paper's basis.
MIN_AUTO_EIGEN = 200
#: Ceiling of the rule: the basis costs O(N K²) to compute and N K doubles to hold.
MAX_AUTO_EIGEN = 1000


def auto_n_eigen(area_m2: float, agent_radius_m: float, n_points: int) -> int:
    """n_K = clip(⌈A / (5 π r_a²)⌉, 200, 1000), and below N/2 (a basis needs K < N).

    Args:
        area_m2: surface area A [m²] (e.g. N h² for a cloud of spacing h, or the mass matrix's sum).
        agent_radius_m: footprint radius r_a [m].
        n_points: N, points of the cloud.
    """
    if not (math.isfinite(area_m2) and area_m2 > 0.0):
        raise ConfigError(f"the surface area must be > 0 m² to choose n_eigen, got {area_m2!r}")
    if not (math.isfinite(agent_radius_m) and agent_radius_m > 0.0):
        raise ConfigError(f"the agent radius must be > 0 m to choose n_eigen, got {agent_radius_m!r}")
    k = math.ceil(area_m2 / (FOOTPRINTS_PER_MODE * math.pi * agent_radius_m**2))
    k = min(max(k, MIN_AUTO_EIGEN), MAX_AUTO_EIGEN)
    return max(1, min(k, n_points // 2))
