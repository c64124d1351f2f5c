"""``python -m fuse4d``: the command-line interface."""

from .cli import main

main()
