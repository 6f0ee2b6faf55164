"""Write the worked example data/film_strip (issue 16): a strip of 30 scanned film photographs with
fiducials, scan pixels, a calibration report and 4 control points at one end.

    python scripts/make_film_strip.py [--out data/film_strip] [--seed 16]

The files come from striptri.simulate.film (truth in <out>/truth/). Re-running with the same seed
writes the same files.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from striptri.simulate.film import FilmOptions, film_project_files
from striptri.io.csvtable import format_csv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="data/film_strip")
    parser.add_argument("--seed", type=int, default=16)
    args = parser.parse_args()
    files, truth = film_project_files(FilmOptions(), seed=args.seed)
    out = Path(args.out)
    (out / "truth").mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (out / name).write_text(text, encoding="utf-8")
    for name, columns in truth.items():
        (out / "truth" / name).write_text(format_csv(columns), encoding="utf-8")
    print(f"wrote {out} ({len(files)} files, truth/{', truth/'.join(truth)})")


if __name__ == "__main__":
    main()
