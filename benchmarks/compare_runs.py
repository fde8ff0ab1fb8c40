"""Compare two finished runs of the workflow table by table: which files are byte-identical, and for the others the
columns added or gone, and the largest relative change of every numeric column that differs (YAML: the keys that
differ, timings left out).

    python benchmarks/compare_runs.py OLD/results NEW/results

Used for issue 37's "behaviour unchanged" (benchmarks/README.md, "The default run before and after the house").
"""
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml


def strip(d):
    """A YAML document without its timings (``seconds``, ``*_seconds``)."""
    if isinstance(d, dict):
        return {k: strip(v) for k, v in d.items() if not str(k).endswith("seconds")}
    if isinstance(d, list):
        return [strip(v) for v in d]
    return d


def compare(a: Path, b: Path, name: str) -> str:
    if name.endswith(".tsv"):
        x, y = pd.read_csv(a, sep="\t"), pd.read_csv(b, sep="\t")
        added = [c for c in y.columns if c not in x.columns]
        gone = [c for c in x.columns if c not in y.columns]
        if len(x) != len(y):
            return f"{name}: rows {len(x)} -> {len(y)}"
        changes = []
        for c in (c for c in x.columns if c in y.columns and not x[c].equals(y[c])):
            try:
                u, v = x[c].to_numpy(float), y[c].to_numpy(float)
                scale = np.nanmax(np.abs(u)) or 1.0
                changes.append(f"{c} (max change {np.nanmax(np.abs(u - v)) / scale:.2g} of its largest value)")
            except ValueError:
                changes.append(f"{c} (text)")
        return f"{name}: added {added}, gone {gone}, differing {changes or 'none'}"
    x, y = yaml.safe_load(a.read_text()), yaml.safe_load(b.read_text())
    if strip(x) == strip(y):
        return f"{name}: the same but for timings"
    keys = sorted(k for k in set(x) | set(y) if strip(x.get(k)) != strip(y.get(k)))
    return f"{name}: differs in {keys}"


def main(old: Path, new: Path) -> None:
    names = sorted(str(p.relative_to(old)) for p in old.rglob("*") if p.is_file()
                   and p.suffix in (".tsv", ".yaml", ".md", ".rst") and "benchmarks" not in p.parts)
    missing = [n for n in names if not (new / n).is_file()]
    extra = sorted(str(p.relative_to(new)) for p in new.rglob("*") if p.is_file()
                   and p.suffix in (".tsv", ".yaml", ".md", ".rst") and "benchmarks" not in p.parts
                   and not (old / p.relative_to(new)).is_file())
    same = [n for n in names if n not in missing and (old / n).read_bytes() == (new / n).read_bytes()]
    print(f"{len(same)} of {len(names)} files byte-identical; only in the old run: {missing}; only in the new: {extra}")
    for name in names:
        if name not in same and name not in missing:
            print(compare(old / name, new / name, name))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
