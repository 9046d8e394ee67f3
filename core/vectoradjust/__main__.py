"""``python -m vectoradjust``: the command line (the same as the ``vectoradjust`` script)."""

import sys

from vectoradjust.cli import main

if __name__ == "__main__":
    sys.exit(main())
