"""Detection benchmark: the paper's Tables 6/7 for every detector, false alarms, speed.

Usage: .venv/bin/python benchmarks/detection.py --json benchmarks/results/detection.json
(the same as `slidewatch bench detection`; see worker/training/benchmark.py).
"""

import sys

from worker.commands.bench import bench

if __name__ == "__main__":
    bench(["detection", *sys.argv[1:]])
