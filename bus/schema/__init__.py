"""The generated protobuf module of ``adaptiveh.proto`` (``scripts/generate_schema.py`` makes it)."""
