"""The library's anchor on the full solver, the shift alone against the first order (issue 50, item 3).

    OMP_NUM_THREADS=1 python benchmarks/anchor_study.py --twin results/VARIANT [--write-card]

For each scope-run library of a built twin: its error at the twin before the anchor (``raw``), and its error against
the full solver near the twin after the anchor, measured as rule ``twin_card`` measures it
(``library_route.anchors``): with the shift alone over the old neighbourhood (5 % of each range; ``order=0``) and to
first order over the box from the twin's own standard deviations (``order=1``, today's card). Prints the table for
benchmarks/README.md and the time of each. ``--write-card`` writes the first-order anchors into the twin's card, as
the rule does (on a copy of a project built before the change: the card's other entries are unchanged).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from hybridtwin.online.library_route import anchors
from hybridtwin.online.twin import load_twin, read_card, write_card


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--twin", type=Path, required=True, help="a built twin's folder (results/VARIANT)")
    parser.add_argument("--write-card", action="store_true", help="write the first-order anchors into its twin.yaml")
    args = parser.parse_args()
    twin = load_twin(args.twin)
    timed = {}
    for order in (0, 1):
        start = time.perf_counter()
        timed[order] = anchors(twin, order=order), time.perf_counter() - start
    (shift, t0), (first, t1) = timed[0], timed[1]
    print("| run | at the twin, before the anchor [%] | shift alone, 5 % of the ranges [%] | first order, the twin's "
          "box [%] | first order, 5 % / 15 % of the ranges [%] | the twin's box (normalised half widths) |\n|---|---|---|---|---|---|")
    for run, entry in first.items():
        half = entry["half_width"]
        wider = " / ".join(f"{w['error_pct']:.3g}" for w in entry["wider"])
        print(f"| {run} | {entry['raw_error_pct']:.3g} | {shift[run]['error_pct'] if run in shift else float('nan'):.3g} "
              f"| {entry['error_pct']:.3g} | {wider} | {min(half):.3g}-{max(half):.3g} |")
    print(f"\nanchors: shift alone {t0:.1f} s, first order {t1:.1f} s (wall, every run)")
    if args.write_card:
        path = args.twin / "twin.yaml"
        card = read_card(path)
        for entry in card["library"]["runs"]:
            entry["anchor"] = first.get(entry["run"])
        write_card(card, path)
        print(f"wrote the first-order anchors into {path}")


if __name__ == "__main__":
    main()
