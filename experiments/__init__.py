"""Runs of many learners in-process: the paper bench (plan, runner, stats, report, figures), training."""
