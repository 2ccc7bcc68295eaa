"""Re-using recent samples: a window of the last transitions, re-scored at each policy update.

A sample's advantage was formed from the critic as it stood when the sample arrived; early in a run
that critic is poor, and each sample moves the policy once. At a segment update the learner can draw
transitions from this window and apply their gradients again, with the TD error re-evaluated by the
critic as it stands now and the score taken at the current mean. The policy moved since the sample was
drawn, so each gradient is weighted by the truncated importance ratio ``min(1, π(a|s)/μ(a|s))`` (``μ``
the policy that drew it), as V-trace and ACER truncate theirs: off-policy samples can shrink a step,
never blow it up.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Transition:
    s: np.ndarray  # normalised state
    raw: np.ndarray  # the unclipped sampled action
    reward: float
    s_next: np.ndarray  # normalised next state
    terminated: bool
    log_prob: float  # log μ(raw | s) under the policy that drew it


class TransitionWindow:
    """The last ``size`` transitions; ``sample`` draws ``n`` of them without replacement."""

    def __init__(self, size: int):
        if size < 1:
            raise ValueError(f"the replay window needs at least 1 transition, got {size}")
        self.items: deque[Transition] = deque(maxlen=size)

    def __len__(self) -> int:
        return len(self.items)

    def push(self, transition: Transition) -> None:
        self.items.append(transition)

    def sample(self, n: int, rng: np.random.Generator) -> list[Transition]:
        n = min(n, len(self.items))
        return [self.items[i] for i in rng.choice(len(self.items), size=n, replace=False)]

    def state_dict(self) -> dict:
        return {"size": self.items.maxlen, "items": list(self.items)}

    def load_state_dict(self, state: dict) -> None:
        self.items = deque(state["items"], maxlen=state["size"])
