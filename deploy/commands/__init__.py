"""One module per ``adaptiveh`` subcommand; each defines ``register(subparsers)``.

The CLI discovers the modules here, so adding a command never edits a shared file.
"""

import logging

LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"


def setup_logging(level: str) -> None:
    """One log format for every process of the stack (their logs end up side by side)."""
    logging.basicConfig(level=level.upper(), format=LOG_FORMAT)
