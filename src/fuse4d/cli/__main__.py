"""``python -m fuse4d.cli``: the command-line interface."""

from . import main

main()
