"""One module per ``adaptiveh`` subcommand; each defines ``register(subparsers)``.

The CLI discovers the modules here, so adding a command never edits a shared file.
"""
