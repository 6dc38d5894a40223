"""``python -m jaxlc.cli``: the command line (same as the ``jaxlc`` script)."""

import sys

from jaxlc.cli import main

if __name__ == "__main__":
    sys.exit(main())
