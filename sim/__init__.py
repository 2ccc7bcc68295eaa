"""The non-stationary environments and the PyBullet Panda scene; importing registers the envs."""

from gymnasium.envs.registration import register, registry


def _register(env_id: str, entry_point: str) -> None:
    if env_id not in registry:
        register(id=env_id, entry_point=entry_point)


_register("NSCartPoleContinuous-v0", "sim.cartpole:NSCartPoleContinuous")
_register("NSPendulum-v0", "sim.pendulum:NSPendulum")
_register("NSReach-v0", "sim.reach:NSReachEnv")
