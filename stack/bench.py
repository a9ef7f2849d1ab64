"""`python -m stack.bench`: the benchmark figures (`stack.cli.bench`)."""

import sys

if __name__ == "__main__":
    from stack.cli.bench import main

    sys.exit(main())
