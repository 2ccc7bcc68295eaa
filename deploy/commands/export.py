"""``adaptiveh export lerobot RECORDING... --out DIR``: recorded runs as a LeRobotDataset (v3).

The columns and how the streams are aligned on the control tick: ``monitor.lerobot_export`` and
``docs/recording.md``. LeRobot is an optional install (the README says how); without it the command says
so and exits 2, as it does for a recording it cannot export.
"""

from __future__ import annotations

import argparse
import json
import logging
import os

from deploy.commands import setup_logging


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export",
        help="export recordings to another format (lerobot: a LeRobotDataset)",
        description="Export recordings (.mcap written by adaptiveh up) to a format a learning library reads.",
    )
    formats = p.add_subparsers(dest="format", required=True)
    lr = formats.add_parser(
        "lerobot",
        help="a LeRobotDataset v3: one episode per environment episode, fps = the control rate",
        description="Write the recordings' episodes as one LeRobotDataset (parquet, mp4, meta/) in --out.",
    )
    lr.add_argument("recordings", nargs="+", help="recordings (.mcap; a split recording: its first part)")
    lr.add_argument("--out", required=True, help="the dataset's folder (new, or empty)")
    lr.add_argument("--repo-id", default=None, help="the dataset's name (default: adaptiveh/<robot>)")
    lr.add_argument(
        "--camera",
        choices=("auto", "frame", "annotated", "none"),
        default="auto",
        help="the video's images: camera/frame (raw RGB, when recorded), camera/annotated (the operator's "
        "JPEG), none; auto: the first of these that was recorded",
    )
    lr.add_argument(
        "--vcodec", default="libsvtav1", help="LeRobot's video codec: libsvtav1 (its default), h264, hevc"
    )
    lr.add_argument("--fps", type=int, default=None, help="the frame rate (default: measured from the ticks)")
    lr.add_argument("--log-level", default="WARNING")
    lr.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from monitor.lerobot_export import ExportError, export
    from tasks.reach import OBSERVATION_NAMES

    setup_logging(args.log_level)
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its whole configuration at every episode
    try:
        report = export(
            args.recordings, args.out, args.repo_id, args.camera, args.vcodec, args.fps, OBSERVATION_NAMES
        )
    except ExportError as exc:
        logging.error("%s", exc)
        return 2
    print(json.dumps(report), flush=True)
    return 0
