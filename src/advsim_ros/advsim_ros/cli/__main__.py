"""`python -m advsim_ros.cli`: the `advsim` command."""

import sys

from advsim_ros.cli import main

sys.exit(main())
