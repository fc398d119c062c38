#!/usr/bin/python3
"""docs/accuracy.md's image-adaptive table, over repeated runs of bench/accuracy.py.

Usage: bench/image_adaptive_table.py OUT_DIR [OUT_DIR ...]
Each OUT_DIR is one run of bench/accuracy.py with the knobs default and image-adaptive (one
view; several OUT_DIRs may split the scenes, e.g. head in one folder and the phantom in
another: pass them as HEAD1,PHANTOM1 HEAD2,PHANTOM2 ...). For each scene, mode and
`--image-adaptive` bound it prints a markdown row: the rays cast (% of the image's pixels),
ms/frame as the median over the runs with the runs' range, the ratio to every pixel cast
(median over the runs of each run's own ratio: both were measured in the same run), PSNR
against the truth, and every pixel cast's ms (median) and PSNR. Rays and pictures do not vary
from run to run; this machine's speed does (up to 1.7x), hence the repeated runs.
"""

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plot_accuracy import load_run  # noqa: E402

MODES = ["dvr-bone", "dvr-soft", "iso", "mip"]


def load(run):
    """One run: the rows of its OUT_DIRs (joined by commas) together."""
    return [r for out in run.split(",") for r in load_run(out, "image_adaptive_table.py")]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", help="one run each: an OUT_DIR, or OUT_DIRs joined by commas")
    p.add_argument("--pixels", type=int, default=512 * 512, help="pixels of the image (512x512)")
    args = p.parse_args()
    runs = [load(run) for run in args.runs]
    ours = [r for r in runs[0] if r["renderer"] == "octoray"]
    keys = sorted({(r["scene"], r["mode"]) for r in ours if r["knob"] == "image-adaptive"},
                  key=lambda k: (k[0] != "head", k[0], MODES.index(k[1]) if k[1] in MODES else 99, k[1]))
    if not keys:
        sys.exit(f"image_adaptive_table.py: {args.runs[0]} has no image-adaptive rows "
                 "(run bench/accuracy.py with --knobs default,image-adaptive)")
    n = len(runs)
    print(f"| scene, mode | bound | rays (% of {args.pixels:,}) | ms/frame, median of {n} (range) | "
          f"× every pixel cast | PSNR dB | every pixel cast: ms, PSNR dB |")
    print("|---|---|---|---|---|---|---|")
    for scene, mode in keys:
        def pick(rows, knob, setting=None):
            found = [r for r in rows if r["renderer"] == "octoray" and r["scene"] == scene and r["mode"] == mode
                     and r["view"] == "0" and r["knob"] == knob and (setting is None or r["setting"] == setting)]
            if len(found) != 1:
                sys.exit(f"image_adaptive_table.py: {len(found)} rows for {scene} {mode} view 0 {knob} "
                         f"{setting or ''} in a run (expected 1)")
            return found[0]
        settings = sorted({r["setting"] for r in ours if (r["scene"], r["mode"], r["knob"]) ==
                           (scene, mode, "image-adaptive")}, key=float)
        full = [pick(rows, "default") for rows in runs]
        full_ms = statistics.median(f["medianMs"] for f in full)
        for setting in settings:
            rows = [pick(run, "image-adaptive", setting) for run in runs]
            ms = [r["medianMs"] for r in rows]
            ratios = [r["medianMs"] / f["medianMs"] for r, f in zip(rows, full)]
            first = rows[0]
            print(f"| {scene}, {mode} | {setting} | {100 * first['raysCast'] / args.pixels:.0f} % | "
                  f"{statistics.median(ms):.0f} ({min(ms):.0f}–{max(ms):.0f}) | {statistics.median(ratios):.2f} | "
                  f"{first['psnrDb']:.1f} | {full_ms:.0f}, {full[0]['psnrDb']:.1f} |")


if __name__ == "__main__":
    main()
