"""The tiny budget of the paper bench's tests (the local run in conftest, the Ray executor's test)."""

# Small networks and early learning so that every baseline trains within the tiny budget.
TINY = {
    "td3": {"learning_starts": 50, "net_arch": [64, 64]},
    "ddpg": {"learning_starts": 50, "net_arch": [64, 64]},
    "sac": {"learning_starts": 50, "net_arch": [64, 64]},
    "ppo": {"n_steps": 64, "batch_size": 32},
}
STEPS = 200
