"""``python -m neck_env.rig``: see :mod:`neck_env.rig.cli`."""

import sys

from .cli import main

sys.exit(main())
