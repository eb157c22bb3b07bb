"""tactex.twin: the protocol-level twin of the real robot, a separate process above the simulation
and the robot stages. franky-sim with our scene speaks libfranka's protocol, the simulated wrist
sensor is served over Net F/T, and the twin paces itself on the robot's clock; :class:`TwinProcess`
starts one for tests and scripts, :class:`FrankaSimProcess` an independent FCI emulator."""

from tactex.twin.config import TwinConfig
from tactex.twin.franka_sim_process import FrankaSimProcess
from tactex.twin.process import TwinProcess
from tactex.twin.scene import export_marking_cloud
from tactex.twin.twin import Twin, run_twin

__all__ = ["FrankaSimProcess", "Twin", "TwinConfig", "TwinProcess", "export_marking_cloud", "run_twin"]
