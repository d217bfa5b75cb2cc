"""``python -m bayescap.cli``: the command line."""

import sys

from bayescap.cli import main

sys.exit(main())
