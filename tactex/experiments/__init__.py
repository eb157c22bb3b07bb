"""Experiments: paper reproductions and single runs with their reports."""

from tactex.experiments.explore import ExploreConfig, ExploreResult, load_explore_cloud, run_explore

__all__ = ["ExploreConfig", "ExploreResult", "load_explore_cloud", "run_explore"]
