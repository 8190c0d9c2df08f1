"""Simulator backends behind one interface (``Backend``); ``make_backend`` picks one by name."""

from __future__ import annotations

from acn.sim.backends.base import (ACTION_MODES, BACKENDS, IMU_ACC_KINDS, Backend, SimConfig, SimulationDiverged,
                                   default_state, simulator_version)

def make_backend(name: str, config: SimConfig | None = None) -> Backend:
    """Build the named simulator (``pybullet`` or ``mujoco``) with ``config``."""
    if name == "pybullet":
        from acn.sim.backends.pybullet_backend import PyBulletBackend

        return PyBulletBackend(config)
    if name == "mujoco":
        from acn.sim.backends.mujoco_backend import MuJoCoBackend

        return MuJoCoBackend(config)
    raise ValueError(f"unknown simulator {name!r}; choose from {', '.join(BACKENDS)}")


__all__ = ["ACTION_MODES", "BACKENDS", "IMU_ACC_KINDS", "Backend", "SimConfig", "SimulationDiverged", "default_state",
           "make_backend", "simulator_version"]
