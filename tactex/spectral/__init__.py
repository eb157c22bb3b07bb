"""Spectral geometry of point clouds: Laplacian, eigenbasis, diffusion, basis cache (TEC eq. 19–21)."""

from tactex.spectral.basis import LaplaceBasis, build_basis, compute_basis, load_basis, save_basis
from tactex.spectral.cache import default_cache_dir
from tactex.spectral.diffusion import ImplicitDiffusion, SpectralDiffusion, diffusion_timestep
from tactex.spectral.eigen import laplace_eigenpairs
from tactex.spectral.laplacian import point_cloud_laplacian

__all__ = [
    "ImplicitDiffusion",
    "LaplaceBasis",
    "SpectralDiffusion",
    "build_basis",
    "compute_basis",
    "default_cache_dir",
    "diffusion_timestep",
    "laplace_eigenpairs",
    "load_basis",
    "point_cloud_laplacian",
    "save_basis",
]
