"""`python -m stack.bench`: the benchmark figures (implemented in `stack.cli.bench`).

The functions this module held before the package was split into layers stay importable here
(``from stack.bench import bench_saturated``).
"""

import sys

from stack.cli.bench import bench_campaign, bench_canstack_pair, bench_python_can_virtual, bench_saturated, main

__all__ = ["bench_python_can_virtual", "bench_canstack_pair", "bench_saturated", "bench_campaign", "main"]

if __name__ == "__main__":
    sys.exit(main())
