"""The non-stationary environments and the PyBullet Panda scene; importing registers the physics-only envs.

``NSReach-v0`` needs robot_io's controller, so ``tasks`` (above robot_io) registers it.
"""

from gymnasium.envs.registration import register, registry


def _register(env_id: str, entry_point: str) -> None:
    if env_id not in registry:
        register(id=env_id, entry_point=entry_point)


_register("NSCartPoleContinuous-v0", "sim.cartpole:NSCartPoleContinuous")
_register("NSPendulum-v0", "sim.pendulum:NSPendulum")
