"""Tasks over the libraries (robot_io, vision, learner, sim); importing registers every environment.

``sim`` registers the environments that need only physics; ``NSReach-v0`` combines sim's PyBullet
scene with robot_io's controller, so it is registered here, above both.
"""

from gymnasium.envs.registration import register, registry

import sim  # noqa: F401  (registers the NS environments of sim)

if "NSReach-v0" not in registry:
    register(id="NSReach-v0", entry_point="tasks.reach_env:NSReachEnv")
