"""One module per ``adaptiveh`` subcommand; each defines ``register(subparsers)``.

The CLI discovers the modules here, so adding a command never edits a shared file.
"""

import argparse
import logging
import os
import sys
from pathlib import Path

from deploy.part_env import TOKEN_ENV

LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"


def add_part_arguments(parser: argparse.ArgumentParser, sections: str, per_arm: bool = False) -> None:
    """The options every part shares: ``--config``, ``--duration``, ``--log-level``; ``per_arm``: an arm's
    part (robot-io, actor, vision) also says which arm of a fleet it serves (``--arm``)."""
    parser.add_argument("--config", default="configs/sim.yaml", help=f"top-level YAML ({sections})")
    parser.add_argument(
        "--duration", type=float, default=0.0, help="stop after this many seconds (0: run until ^C)"
    )
    parser.add_argument("--log-level", default="INFO")
    if per_arm:
        parser.add_argument(
            "--arm", default=None, help="the arm of the config's fleet this part serves (fleet configs only)"
        )


def setup_logging(level: str) -> None:
    """One log format for every process of the stack (their logs end up side by side)."""
    logging.basicConfig(level=level.upper(), format=LOG_FORMAT)


def add_token_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--token-file",
        default="",
        help=f"file (mode 0600) holding the operator token; default: the {TOKEN_ENV} environment variable",
    )


def operator_token(args: argparse.Namespace) -> str:
    """The operator token from ``--token-file`` or ``$ADAPTIVEH_TOKEN`` ("" if neither).

    Never a command-line value: any local user reads another's argv with ``ps``. A token file that
    others can read is refused for the same reason.
    """
    if not args.token_file:
        return os.environ.get(TOKEN_ENV, "")
    st = os.stat(args.token_file)
    if st.st_mode & 0o077:
        mode = oct(st.st_mode & 0o777)
        raise SystemExit(f"{args.token_file}: readable by others (mode {mode}); chmod 600 it")
    with open(args.token_file) as fh:
        return fh.read().strip()


def write_private(path: Path, text: str) -> None:
    """Write ``text`` to a fresh file that only its owner can read: 0600 from its creation, never for a
    moment the umask's 0644. An old file at ``path`` is replaced, not reopened (it may be a link)."""
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)


def token_file_path(robot: str) -> Path:
    """Where a monitor that made up its token leaves it: the per-user runtime directory (a tmpfs that
    dies with the login session) or else ``~/.cache``; the pid keeps two monitors apart."""
    base = os.environ.get("XDG_RUNTIME_DIR") or Path.home() / ".cache"
    return Path(base) / "adaptiveh" / f"{robot}-monitor-{os.getpid()}.token"


def show_token(token: str, robot: str) -> Path | None:
    """Tell the operator a token this process made up, never into a log: on a terminal it is printed;
    else (``> file``, systemd, ``adaptiveh up``'s monitor.log) it goes to a 0600 file whose path is
    printed. Returns that file, for the caller to remove when the token dies with the process."""
    if sys.stdout.isatty():
        print(f"monitor token: {token} (type it into the page once)", flush=True)
        return None
    path = token_file_path(robot)
    write_private(path, token + "\n")
    print(f"monitor token file: {path} (mode 0600)", flush=True)
    return path


TOKEN_HELP = (
    "The page asks for the operator token once and keeps it in the browser tab (sessionStorage), never in "
    f"the URL. A token given with --token-file or ${TOKEN_ENV} (as under adaptiveh up, which prints "
    "it on its own terminal) is never printed. Without one a random token guards the page: printed when "
    "stdout is a terminal, else written to a 0600 file ($XDG_RUNTIME_DIR/adaptiveh/, else "
    "~/.cache/adaptiveh/) whose path is printed and which is removed on exit, so no log holds it. "
    "E-STOP needs no token."
)
