"""The handoff checked before the stack starts: ``adaptiveh up`` refuses a checkpoint the learner would
refuse (another task, observation layout, action bounds or arm) before any part moves the arm."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from common.errors import AdaptiveHError
from deploy.config import StackConfig
from deploy.zenoh_env import ReachSpec, env_settings
from learner.provenance import checkpoint_path
from learner.registry import make_agent

REFUSED = (AdaptiveHError, FileNotFoundError, ValueError)  # what check_policy_source raises for a bad source


def check_policy_source(settings: StackConfig) -> dict[str, Any] | None:
    """What ``learner.policy_from`` hands the learner (``AdaptiveH.start_from``'s record), checked as the
    learner will check it, so ``adaptiveh up`` refuses a wrong checkpoint before any part starts; None
    without a handoff or when the learner resumes its own checkpoint instead. Raises ``HandoffMismatch``
    naming the field, or ``FileNotFoundError``."""
    lc = settings.learner
    if lc.policy_from is None or (Path(lc.checkpoint_dir) / "checkpoint.pkl").exists():
        return None
    if not checkpoint_path(lc.policy_from).is_file():
        raise FileNotFoundError(f"learner.policy_from: no checkpoint at {lc.policy_from}")
    spec = ReachSpec(env_settings(settings))
    agent = make_agent(lc.algo, spec, lc.seed, lc.agent_config())
    return agent.start_from(lc.policy_from)
