"""Perception: depth camera → surface estimates (VA-UFIC §II-B) and target capture (TEC §V-A1).

- :class:`SurfaceEstimator` — synchronous, deterministic ``estimate(frame, world_T_tool)``;
- :class:`AsyncSurfacePipeline` — two threads, ``latest(max_age_ms)`` never blocks;
- :func:`acquire_surface` — RGB-D frames → filtered :class:`~tactex.pointcloud.SurfaceCloud` with target;
- camera model, extrinsics, depth → cloud, recordings, live RealSense source (extra ``realsense``).
"""

from tactex.perception.acquisition import AcquisitionConfig, acquire_surface
from tactex.perception.depth import DepthPoints, check_pose, deproject, depth_in_meters, frame_to_cloud, validate_frame
from tactex.perception.estimate import SurfaceEstimate
from tactex.perception.estimator import PreparedPatch, SurfaceEstimator, SurfaceEstimatorConfig
from tactex.perception.frame import CameraFrame, CameraIntrinsics, D415_DEPTH_640x480, D435I_DEPTH_640x480
from tactex.perception.mount import CameraMount
from tactex.perception.normals import NormalField, grid_normals, knn_normals, smallest_eigpairs
from tactex.perception.pca import SegmentPca, local_curvature, orientation_error, segment_pca
from tactex.perception.pipeline import AsyncSurfacePipeline, FrameSource, PipelineStats, TimedEstimate
from tactex.perception.realsense import RealSenseNotFoundError, RealSenseSource
from tactex.perception.recording import FrameRecorder, RecordedFrameSource, load_frames, save_frames
from tactex.perception.region_growing import RegionGrowingParams, grid_edges, knn_edges, region_growing

__all__ = [
    "AcquisitionConfig",
    "AsyncSurfacePipeline",
    "CameraFrame",
    "CameraIntrinsics",
    "CameraMount",
    "D415_DEPTH_640x480",
    "D435I_DEPTH_640x480",
    "DepthPoints",
    "FrameRecorder",
    "FrameSource",
    "NormalField",
    "PipelineStats",
    "PreparedPatch",
    "RealSenseNotFoundError",
    "RealSenseSource",
    "RecordedFrameSource",
    "RegionGrowingParams",
    "SegmentPca",
    "SurfaceEstimate",
    "SurfaceEstimator",
    "SurfaceEstimatorConfig",
    "TimedEstimate",
    "acquire_surface",
    "check_pose",
    "deproject",
    "depth_in_meters",
    "frame_to_cloud",
    "grid_edges",
    "grid_normals",
    "knn_edges",
    "knn_normals",
    "load_frames",
    "local_curvature",
    "orientation_error",
    "region_growing",
    "save_frames",
    "segment_pca",
    "smallest_eigpairs",
    "validate_frame",
]
