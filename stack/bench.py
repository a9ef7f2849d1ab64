"""`python -m stack.bench`: the benchmark figures (implemented in `stack.cli.bench`)."""

import sys

from stack.cli.bench import main

if __name__ == "__main__":
    sys.exit(main())
