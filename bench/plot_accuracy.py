#!/usr/bin/python3
"""Plots and tables from bench/accuracy.py's output (docs/accuracy.md).

Usage: bench/plot_accuracy.py OUT_DIR [--images DIR] [--view N]
Reads OUT_DIR/rows.csv, truths.csv, scaling.csv and machine.json; writes one PNG per scene and
mode (error against the truth over time per frame, every setting of ours and VTK's, with the
Pareto fronts) into --images (default OUT_DIR), and OUT_DIR/report.md with the tables:
every knob's settings (median over views), VTK at equal error (for each VTK point, our fastest
setting with an error no larger, and the time ratio), each view's defaults and equal-error
ratios, every setting side by side by mode and view, and scaling. With --view N, only that view's rows: OUT_DIR/report-vN.md and
accuracy-SCENE-MODE-vN.png (one view's every knob, not a median over views).
"""

import argparse
import csv
import json
import statistics
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


# Effects change the picture (the truth has none of them): they are timed and shown, but are
# not approximations of the truth, so they take no part in the fronts or the equal-error table.
EFFECTS = {"boundary", "silhouette", "shading"}


def number(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def load(path):
    if not path.exists():
        return []
    with open(path) as f:
        return list(csv.DictReader(f))


def load_run(out, tool, columns=("medianMs", "psnrDb", "ssim", "raysCast")):
    """The rows of one accuracy.py run (OUT/rows.csv), `columns` as numbers; `tool` names the
    script in the message when the folder has none."""
    path = Path(out) / "rows.csv"
    if not path.is_file():
        sys.exit(f"{tool}: {path}: no such file (an OUT_DIR of bench/accuracy.py?)")
    rows = load(path)
    for r in rows:
        for k in columns:
            r[k] = number(r.get(k))
    return rows


def pareto(points):
    """Points (ms, psnr) not beaten by one both faster and more accurate, by time."""
    front, best = [], -1e9
    for ms, db in sorted(points):
        if db > best:
            front.append((ms, db))
            best = db
    return front


def median_rows(rows):
    """Median over views of each (scene, mode, renderer, knob, setting)."""
    groups = defaultdict(list)
    for r in rows:
        groups[(r["scene"], r["mode"], r["renderer"], r["knob"], r["setting"])].append(r)
    out = []
    for key, rs in groups.items():
        m = {"scene": key[0], "mode": key[1], "renderer": key[2], "knob": key[3], "setting": key[4],
             "views": len(rs), "note": "; ".join(sorted({r["note"] for r in rs if r.get("note")}))}
        for c in ["medianMs", "drawMs", "raysCast", "samplesPerPixel", "contributingPerPixel", "residentMiB",
                  "psnrDb", "ssim", "maxAbsError", "depthMeanVoxels", "depthMaxVoxels"]:
            values = [number(r.get(c)) for r in rs if number(r.get(c)) is not None]
            m[c] = statistics.median(values) if values else None
        out.append(m)
    return out


def fastest_as_accurate(ours, psnr, ssim=None):
    """Our fastest setting (an approximation of the truth, not an effect) with PSNR >= psnr
    (and SSIM >= ssim, where given)."""
    candidates = [o for o in ours if number(o.get("psnrDb")) is not None and number(o.get("medianMs")) is not None
                  and number(o["psnrDb"]) >= psnr and o["knob"] not in EFFECTS
                  and (ssim is None or (number(o.get("ssim")) is not None and number(o["ssim"]) >= ssim))]
    return min(candidates, key=lambda o: number(o["medianMs"])) if candidates else None


def per_view(rows):
    """Each view on its own: our defaults against the truth, VTK GPU at its default step, and
    the time ratio at equal error against every VTK setting (ours / VTK; '–' where none of
    ours is as accurate)."""
    out = ["### Each view", "",
           "Per scene, mode and view: our defaults; VTK GPU at its default 0.5-voxel step; the time "
           "ratio ours/VTK at equal error against each VTK GPU and VTK CPU setting, in the order "
           "0.25, 0.5, 1, 2 voxels (and, for VTK CPU, 0.5 voxel with image sample distance 2).", "",
           "| scene | mode | view | ours default: ms, PSNR dB, SSIM | VTK GPU 0.5 vox: ms, PSNR dB | "
           "ratio vs VTK GPU | ratio vs VTK CPU |", "|---|---|---|---|---|---|---|"]
    keys = sorted({(r["scene"], r["mode"], int(r["view"])) for r in rows})
    order = ["0.25vox", "0.5vox", "1.0vox", "2.0vox", "0.5vox-isd2"]
    for scene, mode, view in keys:
        rs = [r for r in rows if r["scene"] == scene and r["mode"] == mode and int(r["view"]) == view]
        ours = [r for r in rs if r["renderer"] == "octoray"]
        default = next((r for r in ours if r["knob"] == "default"), None)
        gpu05 = next((r for r in rs if r["renderer"] == "vtk-gpu" and r["setting"] == "0.5vox"), None)
        ratios = {}
        for name in ("vtk-gpu", "vtk-cpu"):
            cells = []
            for setting in order:
                v = next((r for r in rs if r["renderer"] == name and r["setting"] == setting), None)
                if v is None or number(v.get("medianMs")) is None or number(v.get("psnrDb")) is None:
                    continue
                best = fastest_as_accurate(ours, number(v["psnrDb"]))
                cells.append(f"{number(best['medianMs']) / number(v['medianMs']):.2f}" if best else "–")
            ratios[name] = " / ".join(cells) if cells else "not run"
        d = (f"{fmt(number(default['medianMs']), 0)}, {fmt(number(default['psnrDb']))}, {fmt(number(default['ssim']), 4)}"
             if default and number(default.get("psnrDb")) is not None else "–")
        g = f"{fmt(number(gpu05['medianMs']), 0)}, {fmt(number(gpu05['psnrDb']))}" if gpu05 and number(gpu05.get("psnrDb")) is not None else "–"
        out.append(f"| {scene} | {mode} | {view} | {d} | {g} | {ratios['vtk-gpu']} | {ratios['vtk-cpu']} |")
    return out + [""]


def knobs_by_view(rows):
    """Every setting side by side across the modes and views of each scene: ms per frame and
    PSNR against the truth, one column per (mode, view)."""
    out = []
    for scene in sorted({r["scene"] for r in rows}):
        rs = [r for r in rows if r["scene"] == scene]
        cells = sorted({(r["mode"], int(r["view"])) for r in rs})
        settings = []
        for r in rs:
            key = (r["renderer"], r["knob"], r["setting"])
            if key not in settings:
                settings.append(key)
        out += [f"### {scene}: every setting by mode and view (ms per frame, PSNR dB)", "",
                "| renderer | knob | setting | " + " | ".join(f"{m} v{v}" for m, v in cells) + " |",
                "|---|---|---|" + "---|" * len(cells)]
        for key in settings:
            values = []
            for mode, view in cells:
                r = next((r for r in rs if (r["renderer"], r["knob"], r["setting"]) == key
                          and r["mode"] == mode and int(r["view"]) == view), None)
                ms, db = (number(r.get("medianMs")), number(r.get("psnrDb"))) if r else (None, None)
                values.append(f"{ms:.0f}, {db:.1f}" if ms is not None and db is not None else "–")
            out.append(f"| {key[0]} | {key[1]} | {key[2]} | " + " | ".join(values) + " |")
        out.append("")
    return out


def fmt(v, digits=1):
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out")
    p.add_argument("--images", default="")
    p.add_argument("--view", type=int, default=None, help="only this view's rows")
    args = p.parse_args()
    out = Path(args.out)
    images = Path(args.images) if args.images else out
    images.mkdir(parents=True, exist_ok=True)
    rows = load(out / "rows.csv")
    truths = load(out / "truths.csv")
    scaling = load(out / "scaling.csv")
    suffix, heading = "", ""
    if args.view is not None:
        rows = [r for r in rows if int(r["view"]) == args.view]
        truths = [t for t in truths if int(t["view"]) == args.view]
        scaling = []
        suffix, heading = f"-v{args.view}", f", view {args.view}"
        if not rows:
            raise SystemExit(f"{out / 'rows.csv'}: no rows of view {args.view}")
    machine = json.loads((out / "machine.json").read_text()) if (out / "machine.json").exists() else {}
    med = median_rows(rows)
    report = [f"Measured {machine.get('date', '?')} on `{machine.get('uname', '?')}` ({machine.get('cpus', '?')} CPUs); "
              f"command `{machine.get('command', '?')}`. Times are medians of steady frames (ms per frame, "
              f"the whole frame: working set, upload, raycast, read-back); errors against the converged truth; "
              f"each number the median over the views rendered.", ""]

    # Truths.
    report += ["### The truths", "", "| scene | mode | view | converged | step (mm) | last change (max) | last change PSNR (dB) | seconds | leaf bricks read |",
               "|---|---|---|---|---|---|---|---|---|"]
    for t in truths:
        report.append(f"| {t['scene']} | {t['mode']} | {t['view']} | {t['converged']} | {fmt(number(t['stepMm']), 4)} | "
                      f"{fmt(number(t['lastChangeMax']), 4)} | {fmt(number(t['lastChangePsnrDb']))} | {t['seconds']} | "
                      f"{t.get('leafBricks') or 'all'} |")
    report.append("")
    if len({r["view"] for r in rows}) > 1:
        report += per_view(rows)
        report += knobs_by_view(rows)

    # Knob tables and plots per scene and mode.
    scenes_modes = sorted({(m["scene"], m["mode"]) for m in med})
    for scene, mode in scenes_modes:
        ours = [m for m in med if m["scene"] == scene and m["mode"] == mode and m["renderer"] == "octoray"]
        vtk = [m for m in med if m["scene"] == scene and m["mode"] == mode and m["renderer"].startswith("vtk")]
        report += [f"### {scene}, {mode}{heading}", "",
                   "| renderer | knob | setting | ms/frame | draw ms | rays | samples/image px | contributing/covered px | resident MiB | PSNR dB | SSIM | max err | depth err (vox, mean/max) |",
                   "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for m in ours + vtk:
            depth = f"{fmt(m['depthMeanVoxels'], 3)} / {fmt(m['depthMaxVoxels'], 2)}" if mode == "iso" else "–"
            note = f" ({m['note']})" if m["note"] else ""
            report.append(f"| {m['renderer']} | {m['knob']} | {m['setting']}{note} | {fmt(m['medianMs'])} | {fmt(m['drawMs'])} | "
                          f"{fmt(m['raysCast'], 0)} | {fmt(m['samplesPerPixel'])} | {fmt(m['contributingPerPixel'])} | "
                          f"{fmt(m['residentMiB'])} | {fmt(m['psnrDb'])} | {fmt(m['ssim'], 4)} | {fmt(m['maxAbsError'], 3)} | {depth} |")
        report.append("")

        # Equal error: for each VTK point, our fastest setting at an error no larger.
        if vtk:
            report += [f"Equal error, {scene}, {mode}: for each VTK setting, our fastest setting whose PSNR "
                       f"against the truth is at least VTK's, and our fastest whose PSNR and SSIM both are.", "",
                       "| VTK | setting | VTK ms | VTK PSNR, SSIM | ours (PSNR) | ours ms | ours PSNR, SSIM | "
                       "time ratio ours/VTK | ours (PSNR and SSIM) | ours ms | time ratio |",
                       "|---|---|---|---|---|---|---|---|---|---|---|"]
            for v in vtk:
                if v["medianMs"] is None or v["psnrDb"] is None:
                    continue
                cells = [v["renderer"], v["setting"], fmt(v["medianMs"]), f"{fmt(v['psnrDb'])}, {fmt(v['ssim'], 4)}"]
                best = fastest_as_accurate(ours, v["psnrDb"])
                cells += ([f"{best['knob']} {best['setting']}", fmt(best["medianMs"]),
                           f"{fmt(best['psnrDb'])}, {fmt(best['ssim'], 4)}", f"{best['medianMs'] / v['medianMs']:.2f}"]
                          if best else ["none as accurate", "", "", ""])
                both = fastest_as_accurate(ours, v["psnrDb"], v["ssim"]) if v["ssim"] is not None else None
                cells += ([f"{both['knob']} {both['setting']}", fmt(both["medianMs"]),
                           f"{both['medianMs'] / v['medianMs']:.2f}"] if both else ["none as accurate", "", ""])
                report.append("| " + " | ".join(cells) + " |")
            report.append("")

        # Plot: PSNR against ms per frame.
        fig, ax = plt.subplots(figsize=(7.5, 4.8), dpi=110)
        knobs = sorted({o["knob"] for o in ours})
        cmap = plt.get_cmap("tab20")
        for i, knob in enumerate(k for k in knobs if k not in EFFECTS):
            pts = [(o["medianMs"], o["psnrDb"]) for o in ours if o["knob"] == knob and o["medianMs"] and o["psnrDb"]]
            if pts:
                ax.scatter(*zip(*pts), s=22, color=cmap(i % 20), label=f"octoray {knob}", zorder=3)
        front = pareto([(o["medianMs"], o["psnrDb"]) for o in ours
                        if o["medianMs"] and o["psnrDb"] and o["knob"] not in EFFECTS])
        if front:
            ax.plot(*zip(*front), color="black", lw=1.2, label="octoray Pareto front", zorder=2)
        for name, marker, colour in [("vtk-gpu", "s", "tab:red"), ("vtk-cpu", "^", "tab:purple")]:
            pts = [(v["medianMs"], v["psnrDb"]) for v in vtk if v["renderer"] == name and v["medianMs"] and v["psnrDb"]]
            if pts:
                ax.scatter(*zip(*pts), s=40, marker=marker, color=colour, label=name, zorder=4)
                f = pareto(pts)
                ax.plot(*zip(*f), color=colour, lw=1, ls="--", zorder=2)
        ax.set_xscale("log")
        ax.set_xlabel("ms per frame (median, log scale)")
        ax.set_ylabel("PSNR against the converged truth (dB)")
        ax.set_title(f"{scene}, {mode}{heading}: error against time")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, ncol=2, loc="lower right")
        fig.tight_layout()
        fig.savefig(images / f"accuracy-{scene}-{mode}{suffix}.png")
        plt.close(fig)

    if scaling:
        report += ["### Scaling with dataset size (CT-Bone, 30°/15°)", "",
                   "| size | renderer | ms/frame | first frame ms | peak RSS MiB | note |", "|---|---|---|---|---|---|"]
        for s in scaling:
            report.append(f"| {s['size']} | {s['renderer']} | {fmt(number(s.get('medianMs')))} | {fmt(number(s.get('firstMs')))} | "
                          f"{s.get('peakRssMiB') or '–'} | {s.get('note') or ''} |")
        report.append("")
    (out / f"report{suffix}.md").write_text("\n".join(report) + "\n")
    print(f"{out / f'report{suffix}.md'} and {len(scenes_modes)} plots in {images}")


if __name__ == "__main__":
    main()
