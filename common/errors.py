"""The project's root exception: ``except AdaptiveHError`` catches every error this code raises on purpose."""

from __future__ import annotations


class AdaptiveHError(Exception):
    """Base of the project's own errors (a config key, a refused handoff, ...)."""
