"""``python -m lcpbench.cli``."""

import sys

from lcpbench.cli.app import main

sys.exit(main())
