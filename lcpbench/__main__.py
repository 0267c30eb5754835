"""``python -m lcpbench``: the ``lcpbench`` command, with the same arguments and exit codes."""

import sys

from lcpbench.cli.app import main

if __name__ == "__main__":
    sys.exit(main())
