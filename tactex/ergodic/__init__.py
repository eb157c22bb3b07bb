"""Ergodic exploration on point clouds: spectral HEDAC with a CGA-projected agent (TEC eq. 1–6, 18–33, 48)."""

from tactex.ergodic.agents import Agent, FirstOrderAgent, SecondOrderAgent, make_agent, transport
from tactex.ergodic.command import ExplorationCommand
from tactex.ergodic.config import HedacConfig
from tactex.ergodic.explorer import Exploration, HedacExplorer, explore
from tactex.ergodic.gradient import CUBIC_EXPONENTS, cubic_features, cubic_gradient, cubic_value, fit_cubic
from tactex.ergodic.metrics import coverage_residual, normalized_ergodicity

__all__ = [
    "CUBIC_EXPONENTS",
    "Agent",
    "Exploration",
    "ExplorationCommand",
    "FirstOrderAgent",
    "HedacConfig",
    "HedacExplorer",
    "SecondOrderAgent",
    "coverage_residual",
    "cubic_features",
    "cubic_gradient",
    "cubic_value",
    "explore",
    "fit_cubic",
    "make_agent",
    "normalized_ergodicity",
    "transport",
]
