"""Regenerate ``bus/schema/adaptiveh_pb2.py`` (and ``.pyi``) from ``adaptiveh.proto``.

Needs the dev extra's grpcio-tools (protoc). Run from anywhere: ``python scripts/generate_schema.py``.

The generated module is committed, so running the stack needs only the protobuf runtime.
"""

from __future__ import annotations

import sys
from importlib.resources import files
from pathlib import Path

from grpc_tools import protoc

HERE = Path(__file__).resolve().parent.parent / "bus" / "schema"


def main() -> int:
    include = str(files("grpc_tools") / "_proto")
    args = [
        "protoc",
        f"-I{HERE}",
        f"-I{include}",
        f"--python_out={HERE}",
        f"--pyi_out={HERE}",
        "adaptiveh.proto",
    ]
    return protoc.main(args)


if __name__ == "__main__":
    sys.exit(main())
