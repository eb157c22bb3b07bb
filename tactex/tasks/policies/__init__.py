"""VA-UFIC's force-motion policies: a base (:mod:`.base`), one file per kind, segments in sequence,
the policy file (``tactex wipe --policy FILE.toml``) and the check against a task's limits."""

from tactex.tasks.policies.base import ForceMotionPolicy, ForceRamp, PolicyPoint, PolicySegment
from tactex.tasks.policies.check import PolicyLimits, check_policy, sample_policy
from tactex.tasks.policies.circle import CirclePolicy
from tactex.tasks.policies.figure8 import Figure8Policy
from tactex.tasks.policies.line import LinePolicy
from tactex.tasks.policies.policy_file import POLICY_KINDS, load_policy_file, policy_from_dict
from tactex.tasks.policies.samples import SamplesPolicy, read_samples
from tactex.tasks.policies.sequence import PolicySequence
from tactex.tasks.policies.sinusoid import SinusoidPolicy, sinusoid_xy
from tactex.tasks.policies.spiral import SpiralPolicy
from tactex.tasks.policies.zigzag import ZigzagPolicy

__all__ = [
    "POLICY_KINDS", "CirclePolicy", "Figure8Policy", "ForceMotionPolicy", "ForceRamp", "LinePolicy", "PolicyLimits",
    "PolicyPoint", "PolicySegment", "PolicySequence", "SamplesPolicy", "SinusoidPolicy", "SpiralPolicy", "ZigzagPolicy",
    "check_policy", "load_policy_file", "policy_from_dict", "read_samples", "sample_policy", "sinusoid_xy",
]
