"""The paper bench's quick plan on a tiny budget, run once per session with the local executor: the
paper-bench tests read it, the Ray executor's test compares its runs with it."""

from __future__ import annotations

from pathlib import Path

import pytest
from paper_tiny import STEPS, TINY


@pytest.fixture(scope="session")  # 1-4 minutes: 48 runs (4 settings x 6 methods x 2 seeds), one process each
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    pytest.importorskip("stable_baselines3")
    from experiments.paper import main_paper

    out = tmp_path_factory.mktemp("paper")
    summary = main_paper(quick=True, out=out, jobs=2, seeds=2, steps=STEPS, overrides=TINY, progress=False)
    return out, summary
