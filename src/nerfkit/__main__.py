"""``python -m nerfkit``: the same as the ``nerfkit`` command."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
