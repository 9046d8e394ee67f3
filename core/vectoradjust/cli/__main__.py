"""``python -m vectoradjust.cli``: the ``vectoradjust`` command."""

import sys

from vectoradjust.cli import main

sys.exit(main())
