#!/usr/bin/python3
"""Our cheap image-adaptive settings against VTK CPU at image sample distance 2, interleaved.

Usage: bench/vtk_cpu_interleaved.py BUILD_DIR OUT_DIR [--reps 3] [--modes dvr-bone,dvr-soft]
           [--views 0,1] [--frames 5] [--scene head] [--size 512]

OUT_DIR is a folder of bench/accuracy.py with the scene in it (run first, e.g. `bench/accuracy.py
BUILD_DIR OUT_DIR --scenes head --modes dvr-bone,dvr-soft --views 0,1 --knobs default
--no-scaling --vtk-mappers cpu`, at the same --size): its store and converged truths are used
as they are (`--scene phantom64 --size 64` runs it in seconds on accuracy.py --quick's folder). For each
repetition, mode and view, this renders every setting of SETTINGS with octoray-render and then
VTK CPU at 0.5 voxel and image sample distance 2 (vtk-peer), one right after the other, so that
each ratio ours/VTK compares runs a few seconds apart on this machine, whose speed varies by up
to 1.7x from minute to minute (docs/accuracy.md, "One level above the image"). Prints each run,
then per setting the median time, PSNR and SSIM against the truth, and the median and range of
the per-repetition ratios; writes OUT_DIR/interleaved.csv. Asserts nothing about time.
"""

import argparse
import csv
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from accuracy import MODES, Bench  # noqa: E402

# name: arguments, in voxels of the scene's smallest spacing (s); "L1": one level above the
# image (--image-adaptive-levels 1), else the default two.
SETTINGS = {
    "step 1.5vox + ia 1 L1": lambda s: ["--step", 1.5 * s, "--image-adaptive", 1, "--image-adaptive-levels", 1],
    "step 2vox + ia 1 L1": lambda s: ["--step", 2 * s, "--image-adaptive", 1, "--image-adaptive-levels", 1],
    "step 3vox + ia 1 L1": lambda s: ["--step", 3 * s, "--image-adaptive", 1, "--image-adaptive-levels", 1],
    "step 2vox + ia 0.3 L1": lambda s: ["--step", 2 * s, "--image-adaptive", 0.3, "--image-adaptive-levels", 1],
    "step 2vox + ia 0.2": lambda s: ["--step", 2 * s, "--image-adaptive", 0.2],
    "step 2vox + ia 0.3": lambda s: ["--step", 2 * s, "--image-adaptive", 0.3],
    "step 2vox + ia 0.4": lambda s: ["--step", 2 * s, "--image-adaptive", 0.4],
    "step 2vox + ia 0.5": lambda s: ["--step", 2 * s, "--image-adaptive", 0.5],
    "step 3vox + ia 0.3": lambda s: ["--step", 3 * s, "--image-adaptive", 0.3],
}
VTK = "vtk-cpu 0.5vox-isd2"


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("build")
    p.add_argument("out")
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--modes", default="dvr-bone,dvr-soft")
    p.add_argument("--views", default="0,1")
    p.add_argument("--frames", type=int, default=5)
    p.add_argument("--scene", default="head", help="an accuracy.py scene whose store and truths OUT_DIR holds")
    p.add_argument("--size", type=int, default=512, help="the image size of OUT_DIR's truths")
    args = p.parse_args()
    for mode in args.modes.split(","):
        if mode not in MODES or not mode.startswith("dvr"):
            sys.exit(f"vtk_cpu_interleaved.py: --modes: {mode} is not a DVR mode of bench/accuracy.py")
    # accuracy.py's set-up (paths, presets, xvfb-run for vtk-peer) with its own arguments' defaults.
    bench = Bench(argparse.Namespace(build=args.build, out=args.out, size=args.size, frames=args.frames,
                                     quick=False, big=None, big_zoom=6))
    store = bench.out / "scenes" / f"{args.scene}-uint16.octoray"
    if not store.exists():
        sys.exit(f"vtk_cpu_interleaved.py: {store} is missing: run bench/accuracy.py --scenes {args.scene} "
                 f"into {args.out} first")
    spacing = bench.smallest_spacing(store)
    views = [int(v) for v in args.views.split(",")]
    truths = {}
    for mode in args.modes.split(","):
        for view in views:
            truth = bench.out / f"truth-{args.scene}-{mode}-v{view}.exr"
            if not truth.exists():
                sys.exit(f"vtk_cpu_interleaved.py: {truth} is missing: run bench/accuracy.py --scenes {args.scene} "
                         f"--modes {mode} --views {view} into {args.out} first")
            truths[(mode, view)] = truth

    exr = bench.out / "interleaved.exr"
    png = bench.out / "interleaved.png"
    rows = []
    for rep in range(args.reps):
        for (mode, view), truth in truths.items():
            for name in [*SETTINGS, VTK]:
                if name == VTK:
                    cmd = bench.vtk_cmd(store, "cpu", mode, view,
                                        ["--step", 0.5 * spacing, "--image-sample-distance", 2], png, exr)
                else:
                    cmd = bench.ours_cmd(store, args.scene, mode, view, SETTINGS[name](spacing), png, exr)
                out = bench.run(cmd).stdout
                report = json.loads(out[out.find("{"):])
                m = bench.compare(truth, exr, spacing)
                row = {"rep": rep, "mode": mode, "view": view, "setting": name, "medianMs": report["medianMs"],
                       "raysCast": report["frames"][0].get("raysCast") if "frames" in report else None,
                       "psnrDb": m["psnrDb"], "ssim": m["ssim"]}
                rows.append(row)
                print(rep, mode, view, name, round(row["medianMs"], 1), round(m["psnrDb"], 2), round(m["ssim"], 4),
                      row["raysCast"], flush=True)
    with open(bench.out / "interleaved.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)

    print("\n| mode, view | setting | rays | ms (median) | PSNR dB | SSIM | ratio to VTK CPU isd 2 (median, range) |")
    print("|---|---|---|---|---|---|---|")
    for (mode, view) in truths:
        vtk = {r["rep"]: r for r in rows if (r["mode"], r["view"], r["setting"]) == (mode, view, VTK)}
        for name in [*SETTINGS, VTK]:
            mine = [r for r in rows if (r["mode"], r["view"], r["setting"]) == (mode, view, name)]
            ratios = [r["medianMs"] / vtk[r["rep"]]["medianMs"] for r in mine]
            first = mine[0]
            meets = name != VTK and first["psnrDb"] >= vtk[0]["psnrDb"] and first["ssim"] >= vtk[0]["ssim"]
            print(f"| {mode}, {view} | {name}{' (meets VTK)' if meets else ''} | {first['raysCast'] or '-'} | "
                  f"{statistics.median(r['medianMs'] for r in mine):.1f} | {first['psnrDb']:.2f} | {first['ssim']:.4f} | "
                  f"{statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f}) |")


if __name__ == "__main__":
    main()
