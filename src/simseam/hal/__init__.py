"""Hardware abstraction: a simulated rollout driven like a real robot (see ``sim_attached``)."""

from simseam.hal.sim_attached import JointState, NotConnectedError, SimAttachedHAL

__all__ = ["JointState", "NotConnectedError", "SimAttachedHAL"]
