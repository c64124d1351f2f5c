"""``python -m fuse4d``: the command-line interface."""

if __name__ == "__main__":
    from .cli import main

    main()
