"""``python -m hbvs_cli``: the same as the ``hbvs`` command."""

from hbvs_cli.cli.app import main

if __name__ == "__main__":
    main()
