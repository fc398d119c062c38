#!/usr/bin/python3
"""Issue 12's bar against VTK's CPU mapper, over repeated runs of bench/accuracy.py.

Usage: bench/vtk_cpu_bar.py OUT_DIR [OUT_DIR ...] [--modes dvr-bone,dvr-soft]
Each OUT_DIR is one run of bench/accuracy.py with VTK CPU in it (the same scenes, modes and
views in each). For every scene, mode and view, and for each VTK CPU point (0.25 / 0.5 / 1 / 2
voxels / 0.5 voxel at image sample distance 2), it finds in each run our fastest setting whose
PSNR against the truth is at least VTK's, and our fastest whose PSNR and SSIM both are
(plot_accuracy.fastest_as_accurate), and prints a markdown table: VTK's time at image sample
distance 2 (median over the runs), its PSNR and SSIM (first run), and the time ratios ours/VTK
CPU, each the median over the runs, with the range of the second over the runs. This machine's
speed varies from run to run, so one run's ratios are not enough (docs/accuracy.md, "One level
above the image").
"""

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plot_accuracy import fastest_as_accurate, load_run  # noqa: E402

POINTS = ["0.25vox", "0.5vox", "1.0vox", "2.0vox", "0.5vox-isd2"]
NAMES = {"dvr-bone": "CT-Bone", "dvr-soft": "soft tissue"}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out", nargs="+", help="bench/accuracy.py output folders, one per run")
    p.add_argument("--modes", default="dvr-bone,dvr-soft")
    args = p.parse_args()
    runs = [load_run(out, "vtk_cpu_bar.py") for out in args.out]
    keys = sorted({(r["scene"], r["mode"], int(r["view"])) for r in runs[0] if r["renderer"] == "vtk-cpu"
                   and r["mode"] in args.modes.split(",")},
                  key=lambda k: (k[0], args.modes.split(",").index(k[1]), k[2]))
    if not keys:
        sys.exit(f"vtk_cpu_bar.py: {args.out[0]}/rows.csv has no VTK CPU rows in {args.modes} "
                 "(run bench/accuracy.py without --no-vtk)")
    print("| scene, mode, view | VTK CPU isd 2: ms, PSNR dB, SSIM | by PSNR | by PSNR and SSIM | "
          f"by PSNR and SSIM, range of the {len(runs)} runs |")
    print("|---|---|---|---|---|")
    for scene, mode, view in keys:
        by_psnr = {o: [] for o in POINTS}
        by_both = {o: [] for o in POINTS}
        isd2 = []
        for rows in runs:
            here = [r for r in rows if (r["scene"], r["mode"], int(r["view"])) == (scene, mode, view)]
            ours = [r for r in here if r["renderer"] == "octoray"]
            vtk = {r["setting"]: r for r in here if r["renderer"] == "vtk-cpu"}
            missing = [o for o in POINTS if o not in vtk or vtk[o]["medianMs"] is None]
            if missing:
                sys.exit(f"vtk_cpu_bar.py: a run has no VTK CPU time at {', '.join(missing)} for {scene} {mode} view {view}")
            for o in POINTS:
                v = vtk[o]
                for target, match in ((by_psnr, fastest_as_accurate(ours, v["psnrDb"])),
                                      (by_both, fastest_as_accurate(ours, v["psnrDb"], v["ssim"]))):
                    target[o].append(match["medianMs"] / v["medianMs"] if match else float("inf"))
            isd2.append(vtk["0.5vox-isd2"])

        def medians(d):
            return " / ".join(f"{statistics.median(d[o]):.2f}" for o in POINTS)

        ranges = " / ".join(f"{min(by_both[o]):.2f}–{max(by_both[o]):.2f}" for o in POINTS)
        first = isd2[0]
        print(f"| {scene}, {NAMES.get(mode, mode)}, {view} | {statistics.median(i['medianMs'] for i in isd2):.0f}, "
              f"{first['psnrDb']:.1f}, {first['ssim']:.3f} | {medians(by_psnr)} | {medians(by_both)} | {ranges} |")


if __name__ == "__main__":
    main()
