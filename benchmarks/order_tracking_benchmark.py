"""Order tracking speed: a 60 s record at 5 kHz, two channels (target <= 2 s).

    OMP_NUM_THREADS=1 python benchmarks/order_tracking_benchmark.py

The closed-form run-up of tests/swept_signals.py (300 -> 1000 RPM, 300 000 samples, x and y); times the speed
profile and the order vectors (H = 5, windows of 6 revolutions), best and median of 5.
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from swept_signals import swept_record  # noqa: E402

from hybridtwin.data.order_tracking import track_orders  # noqa: E402


def main() -> None:
    record = swept_record(seed=0)
    times = []
    for _ in range(5):
        start = time.perf_counter()
        table = track_orders(record)
        times.append(time.perf_counter() - start)
    print(f"{record.time_s.size} samples ({record.time_s[-1] - record.time_s[0]:.1f} s at 5 kHz), "
          f"{len(record.channels)} channels, {len(table)} windows: track_orders best {min(times):.2f} s, "
          f"median {np.median(times):.2f} s (target <= 2 s)")


if __name__ == "__main__":
    main()
