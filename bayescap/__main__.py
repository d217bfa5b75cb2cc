"""``python -m bayescap``: the command line."""

import sys

from bayescap.cli import main

sys.exit(main())
