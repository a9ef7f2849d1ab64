"""`python -m stack.cli`: the `canstack` command."""

import sys

from stack.cli import main

sys.exit(main())
