"""``python -m vectoradjust.simulate OUT_DIR``: write a simulated project."""

import sys

from vectoradjust.simulate import main

sys.exit(main())
