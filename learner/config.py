"""Hyperparameters of the RKHS learners, validated on construction so a bad config names its key."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from learner.retreat import MODES


def _check(cond: bool, key: str, msg: str) -> None:
    if not cond:
        raise ValueError(f"{key}: {msg}")


@dataclass
class AdaptiveHConfig:
    """Defaults are the ones that learn NS CartPole; see the README for why each differs from the paper.

    ``alpha`` is the step per sample: a segment of length H moves ``h`` by ``alpha·H·mean_t(...)``, so
    AdaptiveH and the fixed-H learner compare at the same per-sample step whatever H is.
    """

    gamma: float = 0.99
    alpha: float = 0.02
    sigma: float = 0.3  # exploration std, as a fraction of the action half-range
    bandwidth: float | list[float] = 0.4  # on states normalised to [-1, 1]
    policy_budget: int = 300
    policy_ald: float = 0.05
    critic: str = "value"  # value | compatible
    critic_budget: int = 300
    critic_ald: float = 0.05
    critic_forgetting: float = 0.999
    critic_p0: float = 10.0
    retreat: str = "local"  # local | smoothed | literal | off
    retreat_smoothing: float = 0.05  # λ of the gradient-field average
    retreat_threshold: float | None = None  # None: derived from the paper (see learner/retreat.py)
    epsilon: float = 1.0  # the ε of Theorem 1, used by the literal threshold Z ε / 2
    h_max: int = 50
    fixed_h: int = 10  # segment length of the fixed-H learner (retreat off)
    weight_decay: float = 1e-3
    max_grad_norm: float = 100.0
    use_discount_factor: bool = True  # the paper's 1/(1-γ) in eq. 8

    def __post_init__(self) -> None:
        for f in fields(self):  # YAML reads 1e-3 (no dot) as a string: coerce it, or name the key
            value = getattr(self, f.name)
            if isinstance(value, str) and ("float" in f.type or f.type == "int"):
                try:
                    setattr(self, f.name, int(value) if f.type == "int" else float(value))
                except ValueError:
                    raise ValueError(f"{f.name}: must be a number, got {value!r}") from None
        _check(0.0 < self.gamma < 1.0, "gamma", f"must be in (0, 1), got {self.gamma}")
        _check(self.alpha > 0, "alpha", f"must be > 0, got {self.alpha}")
        _check(self.sigma > 0, "sigma", f"must be > 0, got {self.sigma}")
        bws = self.bandwidth if isinstance(self.bandwidth, list) else [self.bandwidth]
        _check(all(b > 0 for b in bws), "bandwidth", f"must be > 0, got {self.bandwidth}")
        _check(self.policy_budget >= 1, "policy_budget", f"must be >= 1, got {self.policy_budget}")
        _check(self.critic_budget >= 1, "critic_budget", f"must be >= 1, got {self.critic_budget}")
        _check(0.0 <= self.policy_ald < 1.0, "policy_ald", f"must be in [0, 1), got {self.policy_ald}")
        _check(0.0 <= self.critic_ald < 1.0, "critic_ald", f"must be in [0, 1), got {self.critic_ald}")
        _check(
            self.critic in ("value", "compatible"), "critic", f"must be value|compatible, got {self.critic!r}"
        )
        _check(
            0.0 < self.critic_forgetting <= 1.0,
            "critic_forgetting",
            f"must be in (0, 1], got {self.critic_forgetting}",
        )
        _check(self.critic_p0 > 0, "critic_p0", f"must be > 0, got {self.critic_p0}")
        _check(self.retreat in MODES, "retreat", f"must be one of {MODES}, got {self.retreat!r}")
        _check(
            0.0 < self.retreat_smoothing <= 1.0,
            "retreat_smoothing",
            f"must be in (0, 1], got {self.retreat_smoothing}",
        )
        _check(self.epsilon > 0, "epsilon", f"must be > 0, got {self.epsilon}")
        _check(self.h_max >= 1, "h_max", f"must be >= 1, got {self.h_max}")
        _check(self.fixed_h >= 1, "fixed_h", f"must be >= 1, got {self.fixed_h}")
        _check(self.weight_decay >= 0, "weight_decay", f"must be >= 0, got {self.weight_decay}")
        _check(self.max_grad_norm > 0, "max_grad_norm", f"must be > 0, got {self.max_grad_norm}")

    def to_dict(self) -> dict:
        return asdict(self)
