"""The ``adaptiveh`` command line: discovers the subcommands in ``deploy.commands``."""

from __future__ import annotations

import os

# Small kernel matrices: multi-threaded BLAS only adds contention (measured up to 10x slower).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import faulthandler  # noqa: E402
import importlib  # noqa: E402
import logging  # noqa: E402
import pkgutil  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402

from bus.security import set_command_identity  # noqa: E402
from common.config import ConfigError  # noqa: E402
from deploy import commands  # noqa: E402
from deploy.part_env import die_with_supervisor  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="adaptiveh", description="AdaptiveH learner and robot stack")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(subparsers)
    return parser


def _dump_stacks_on_sigusr1() -> None:
    """``kill -USR1 <pid>`` prints every thread's stack to stderr (the part's log): for hangs.

    Needs stderr to be a real file; under a test's captured stderr there is nothing to dump to.
    """
    try:
        sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return
    if hasattr(faulthandler, "register"):
        faulthandler.register(signal.SIGUSR1, all_threads=True)


def main(argv: list[str] | None = None) -> int:
    _dump_stacks_on_sigusr1()
    die_with_supervisor()
    args = build_parser().parse_args(argv)
    set_command_identity(args.command)  # whose certificate and credentials a secured bus wants
    try:
        return int(args.func(args) or 0)
    except ConfigError as exc:  # every command loads its config the same way; say what is wrong, once
        logging.error("%s", exc)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


def entry() -> None:
    """The process entry (the ``adaptiveh`` script, ``python -m deploy.cli``): an unexpected error is
    logged and ends the process at once. Without ``os._exit`` a part whose start failed (its port taken)
    stayed alive on Zenoh's threads after the traceback, so ``adaptiveh up`` neither restarted it nor
    ended the run (measured)."""
    try:
        code = main()
    except Exception:
        logging.exception("adaptiveh %s failed", " ".join(sys.argv[1:2]))
        logging.shutdown()
        sys.stderr.flush()
        os._exit(1)
    sys.exit(code)


if __name__ == "__main__":
    entry()
