"""``python -m fuse4d.cli``: the command-line interface."""

if __name__ == "__main__":
    from . import main

    main()
