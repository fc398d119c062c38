#!/usr/bin/python3
"""What accuracy costs in time (issue 12, docs/accuracy.md).

Every knob of the GPU raycaster swept with the others at their defaults, on fixed scenes, each
setting measured against the converged truth (octoray-render --reference --converge, the CPU
reference driven to convergence by step halving, pre-integrated for DVR, no early ray
termination); VTK's two mappers
(bench/vtk_peer.cpp) swept over their sample distances in the same run; scaling with dataset
size. Writes OUT/rows.csv (one row per rendered setting) and OUT/truths.csv; bench/
plot_accuracy.py turns them into plots and the tables of docs/accuracy.md. Asserts nothing
about time: CI runs `--quick` so the script cannot rot.

Usage: bench/accuracy.py BUILD_DIR OUT_DIR [--quick] [--scenes head,phantom512[,big]]
           [--modes dvr-bone,dvr-soft,iso,mip] [--views 3|1,2] [--size 512] [--frames 5]
           [--big STORE [--big-zoom 6]] [--no-vtk] [--vtk-mappers gpu,cpu] [--no-scaling] [--knobs step,lod,...]
The scene 'big' (the 8 GiB phantom, --big) is viewed zoomed in (--big-zoom): its truth is the
converged reference over the leaf bricks in view only (octoray-render --reference
--frustum-cut; the whole volume would need 17 GiB of floats), and VTK, which needs the whole
volume in memory, is not run on it (the scaling table shows it failing).
Environment: OCTORAY_SHARED (default: ../shared beside the repository).
"""

import argparse
import csv
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
VIEWS = [(30, 15), (120, -20), (250, 40)]
MODES = {
    # name: octoray-render arguments (TF from Slicer's presets.xml or ours)
    "dvr-bone": ["--slicer", "CT-Bone", "--no-gradient-opacity"],
    "dvr-soft": ["--preset", "soft-tissue"],
    "iso": ["--mode", "iso", "--iso", "300", "--preset", "bone"],
    "mip": ["--mode", "mip", "--preset", "bone"],
}
COLUMNS = ["scene", "mode", "view", "renderer", "knob", "setting", "medianMs", "drawMs", "raysCast",
           "samplesPerPixel", "contributingPerPixel", "workingSetBricks", "residentMiB", "psnrDb",
           "ssim", "maxAbsError", "depthMeanVoxels", "depthMaxVoxels", "depthMissPixels", "note"]


def log(message):
    print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


class Bench:
    def __init__(self, args):
        self.args = args
        self.bin = Path(args.build).resolve() / "bin"
        self.out = Path(args.out).resolve()
        self.out.mkdir(parents=True, exist_ok=True)
        shared = Path(os.environ.get("OCTORAY_SHARED", REPO.parent / "shared"))
        self.presets = shared / "data/presets/slicer/presets.xml"
        self.head = shared / "data/dicom/dcm_qa_ct/Philips/S21570/S2020"
        self.size = f"{args.size}x{args.size}"
        self.rows = []
        self.truths = []
        self.vtk_prefix = []
        if not os.environ.get("DISPLAY"):
            if shutil.which("xvfb-run") is None:
                sys.exit("accuracy.py: no DISPLAY and no xvfb-run for vtk-peer")
            self.vtk_prefix = ["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24 -noreset"]

    def run(self, cmd, check=True):
        result = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
        if check and result.returncode != 0:
            raise RuntimeError(f"{' '.join(map(str, cmd))}\n{result.stderr[-2000:]}")
        return result

    def tf_args(self, mode):
        args = []
        spec = MODES[mode]
        i = 0
        while i < len(spec):
            if spec[i] == "--slicer":
                args += ["--tf", self.presets, "--tf-name", spec[i + 1]]
                i += 2
            else:
                args.append(spec[i])
                i += 1
        return args

    # ---- scenes ----
    def scene(self, name):
        """Store paths of a scene: {'uint16': ..., 'float32': ..., 'gradients': ...}."""
        d = self.out / "scenes"
        d.mkdir(exist_ok=True)
        if name == "big":
            return {"uint16": Path(self.args.big).resolve()}
        source = None
        if name == "head":
            source = self.head
        elif name.startswith("phantom"):
            n = int(name[len("phantom"):])
            source = d / f"{name}.nhdr"
            if not source.exists():
                log(f"phantom {n}^3")
                self.run([self.bin / "octoray-phantom", "--size", f"{n}x{n}x{n}", "-o", source])
        stores = {}
        variants = {"uint16": []} if self.args.quick else {"uint16": [], "float32": ["--store-format", "float32"],
                                                         "gradients": ["--gradients"]}
        for variant, extra in variants.items():
            store = d / f"{name}-{variant}.octoray"
            # kept from an earlier run unless octoray-import is newer (its store format may differ)
            importer = self.bin / "octoray-import"
            if not store.exists() or (importer.exists() and store.stat().st_mtime < importer.stat().st_mtime):
                log(f"import {source} -> {store.name}")
                self.run([self.bin / "octoray-import", source, "-o", store, "--border", "2", *extra])
            stores[variant] = store
        return stores

    def smallest_spacing(self, store):
        """The store's smallest voxel spacing (mm): 4 x the renderers' default step."""
        r = json.loads(self.run([self.bin / "octoray-render", store, "-o", self.out / "probe.png",
                                 "--preset", "bone", "--size", "8x8", "--json"]).stdout)
        return 4 * r["stepMm"]

    def view_args(self, scene, view):
        az, el = VIEWS[view]
        zoom = ["--zoom", self.args.big_zoom] if scene == "big" else []
        return ["--azimuth", az, "--elevation", el, *zoom]

    # ---- truth ----
    def truth(self, scene, store, mode, view):
        name = f"truth-{scene}-{mode}-v{view}"
        exr = self.out / f"{name}.exr"
        meta = self.out / f"{name}.json"
        if not exr.exists():
            cmd = [self.bin / "octoray-render", store, "--reference", "--converge", "-o", self.out / f"{name}.png",
                   "--exr", exr, "--size", self.size, *self.view_args(scene, view), "--json",
                   "--converge-max-change", "0.01", "--converge-psnr", "60", "--early-termination", "1",
                   *self.tf_args(mode)]
            if mode.startswith("dvr"):
                cmd += ["--preintegration", "on"]
            if scene == "big":
                cmd.append("--frustum-cut")
            log(f"truth {name}")
            start = time.time()
            r = self.run(cmd, check=False)
            if r.returncode not in (0, 3):
                raise RuntimeError(r.stderr[-2000:])
            report = json.loads(r.stdout)
            report["seconds"] = time.time() - start
            meta.write_text(json.dumps(report, indent=1))
        report = json.loads(meta.read_text())
        c = report.get("convergence", {})
        self.truths.append({"scene": scene, "mode": mode, "view": view, "converged": c.get("converged"),
                            "stepMm": report["stepMm"], "lastChangeMax": (c.get("changeMax") or [None])[-1],
                            "lastChangePsnrDb": (c.get("changePsnrDb") or [None])[-1],
                            "seconds": round(report.get("seconds", 0), 1),
                            "leafBricks": report.get("frustumCut", {}).get("leaves")})
        return exr

    def compare(self, truth, exr, spacing):
        m = json.loads(self.run([self.bin / "octoray-compare", truth, exr, "--json"]).stdout)
        d = m.get("depth", {})
        return {"psnrDb": m["psnrDb"] if m["psnrDb"] is not None else 200.0, "ssim": m["ssim"],
                "maxAbsError": m["maxAbsError"],
                "depthMeanVoxels": d.get("meanAbsMm", 0) / spacing, "depthMaxVoxels": d.get("maxAbsMm", 0) / spacing,
                "depthMissPixels": d.get("pixelsOne", 0)}

    # ---- the timed commands (also bench/vtk_cpu_interleaved.py's) ----
    def ours_cmd(self, store, scene, mode, view, extra, png, exr):
        """octoray-render of one setting: --frames timed frames, --json, the picture to png and exr."""
        return [self.bin / "octoray-render", store, "-o", png, "--exr", exr, "--size", self.size,
                *self.view_args(scene, view), "--frames", self.args.frames, "--orbit", "0", "--json",
                *self.tf_args(mode), *extra]

    def vtk_cmd(self, store, mapper, mode, view, extra, png, exr):
        """vtk-peer with VTK's 'gpu' or 'cpu' mapper, as ours_cmd (under xvfb-run without a display)."""
        az, el = VIEWS[view]
        return [*self.vtk_prefix, self.bin / "vtk-peer", store, "--mapper", mapper, "-o", png, "--exr", exr,
                "--size", self.size, "--azimuth", az, "--elevation", el, "--frames", self.args.frames, "--json",
                *self.tf_args(mode), *extra]

    # ---- ours ----
    def ours(self, scene, store, mode, view, knob, setting, extra, truth, spacing):
        name = f"gpu-{scene}-{mode}-v{view}-{knob}-{setting}".replace("/", "_")
        exr = self.out / f"{name}.exr"
        r = self.run(self.ours_cmd(store, scene, mode, view, extra, self.out / f"{name}.png", exr), check=False)
        row = {"scene": scene, "mode": mode, "view": view, "renderer": "octoray", "knob": knob,
               "setting": setting}
        if r.returncode != 0:
            row["note"] = r.stderr.strip().splitlines()[-1][:200] if r.stderr.strip() else f"exit {r.returncode}"
            self.rows.append(row)
            return
        report = json.loads(r.stdout)
        frames = report["frames"]
        row.update({"medianMs": report["medianMs"], "drawMs": statistics.median(f["drawMs"] for f in frames),
                    "raysCast": frames[0].get("raysCast"),
                    # samples taken over the image's pixels (rays of every pyramid level included)
                    "samplesPerPixel": (frames[0]["samplesTaken"] / (self.args.size * self.args.size)
                                        if frames[0].get("samplesTaken", -1) >= 0 else None),
                    "contributingPerPixel": frames[0].get("contributingSamplesPerPixel"),  # per covered pixel
                    "workingSetBricks": frames[0].get("workingSetBricks"),
                    "residentMiB": frames[0].get("poolBytesUsed", 0) / 2**20 if "poolBytesUsed" in frames[0] else None})
        row.update(self.compare(truth, exr, spacing))
        self.rows.append(row)

    def sweep(self, scene, stores, mode, view, truth, spacing):
        s = spacing
        knobs = {
            "default": [("default", [])],
            "step": [(f"{f}vox", ["--step", f * s]) for f in (0.125, 0.5, 1.0, 2.0)],
            "lod": [(str(v), ["--lod-pixels", v]) for v in (0, 2, 4, 8)],
            "termination": [(str(v), ["--early-termination", v]) for v in (0.9, 0.95, 1.0)],
            "preintegration": [(f"on@{f}vox", ["--preintegration", "on"] + (["--step", f * s] if f else []))
                               for f in (0, 1.0, 2.0)],
            "jitter": [(f"on@{f}vox", ["--jitter"] + (["--step", f * s] if f else [])) for f in (0, 1.0, 2.0)],
            "image-adaptive": [(str(v), ["--image-adaptive", v]) for v in (0.005, 0.01, 0.02, 0.05, 0.1)],
            # Cheap ends: coarse steps with fewer rays (the fixed cost per ray dominates there).
            "combined": [("step 4vox", ["--step", 4 * s]),
                         ("step 2vox + ia 0.05", ["--step", 2 * s, "--image-adaptive", 0.05]),
                         ("step 4vox + ia 0.05", ["--step", 4 * s, "--image-adaptive", 0.05]),
                         ("step 2vox + ia 0.1", ["--step", 2 * s, "--image-adaptive", 0.1]),
                         ("step 4vox + ia 0.1", ["--step", 4 * s, "--image-adaptive", 0.1]),
                         ("step 2vox + ia 0.3", ["--step", 2 * s, "--image-adaptive", 0.3]),
                         # a bound of 1 is never exceeded (premultiplied channels): 1/16 of the
                         # rays, the rest interpolated, as VTK CPU's image sample distance 4
                         ("step 2vox + ia 1", ["--step", 2 * s, "--image-adaptive", 1]),
                         # one level above the image, nothing refined: a quarter of the rays,
                         # the rest interpolated, as VTK CPU's image sample distance 2
                         ("step 1vox + ia 1 L1", ["--step", s, "--image-adaptive", 1,
                                                  "--image-adaptive-levels", 1]),
                         ("step 1.5vox + ia 1 L1", ["--step", 1.5 * s, "--image-adaptive", 1,
                                                    "--image-adaptive-levels", 1]),
                         ("step 2vox + ia 1 L1", ["--step", 2 * s, "--image-adaptive", 1,
                                                  "--image-adaptive-levels", 1])],
            "gradients": [("precomputed", ["--gradient-pool"])],
            "bricks": [("float32", [])],
            "shading": [("off", ["--shading", "off"]), ("on", ["--shading", "on"])],
            "boundary": [("0,1,1", ["--boundary", "0,1,1"])],
            "silhouette": [("0,1,1", ["--silhouette", "0,1,1"])],
        }
        wanted = self.args.knobs.split(",") if self.args.knobs else list(knobs)
        dvr_only = {"preintegration", "jitter", "boundary", "silhouette", "termination"}
        for knob in wanted:
            if knob in dvr_only and not mode.startswith("dvr"):
                continue
            if knob == "gradients" and "gradients" not in stores:
                continue
            if knob == "bricks" and "float32" not in stores:
                continue
            for setting, extra in knobs[knob]:
                store = stores["gradients"] if knob == "gradients" else stores["float32"] if knob == "bricks" else stores["uint16"]
                self.ours(scene, store, mode, view, knob, setting, extra, truth, spacing)

    # ---- VTK ----
    def vtk(self, scene, store, mode, view, truth, spacing):
        # VTK CPU has no isosurface mode
        mappers = [m for m in (["gpu"] if mode == "iso" else ["gpu", "cpu"])
                   if m in self.args.vtk_mappers.split(",")]
        for mapper in mappers:
            settings = [(f"{f}vox", ["--step", f * spacing]) for f in (0.25, 0.5, 1.0, 2.0)]
            if mapper == "cpu":
                settings += [("0.5vox-isd2", ["--step", 0.5 * spacing, "--image-sample-distance", 2])]
            for setting, extra in settings:
                name = f"vtk{mapper}-{scene}-{mode}-v{view}-{setting}"
                exr = self.out / f"{name}.exr"
                r = self.run(self.vtk_cmd(store, mapper, mode, view, extra, self.out / f"{name}.png", exr),
                             check=False)
                row = {"scene": scene, "mode": mode, "view": view, "renderer": f"vtk-{mapper}", "knob": "step",
                       "setting": setting}
                if r.returncode != 0:
                    row["note"] = (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1][:200]
                else:
                    report = json.loads(r.stdout[r.stdout.find("{"):])
                    row["medianMs"] = report["medianMs"]
                    row.update(self.compare(truth, exr, spacing))
                self.rows.append(row)

    # ---- scaling ----
    def scaling(self):
        sizes = [64, 128] if self.args.quick else [64, 128, 256, 512]
        results = []
        for n in sizes:
            stores = self.scene(f"phantom{n}")
            store = stores["uint16"]
            for renderer in ["octoray", "vtk-gpu", "vtk-cpu"]:
                results.append(self.scale_point(renderer, f"{n}^3", store))
        if self.args.big:
            for renderer in ["octoray", "vtk-gpu", "vtk-cpu"]:
                results.append(self.scale_point(renderer, "big", Path(self.args.big).resolve()))
        with open(self.out / "scaling.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["size", "renderer", "medianMs", "firstMs", "peakRssMiB", "note"])
            w.writeheader()
            w.writerows(results)

    def scale_point(self, renderer, size, store):
        tf = ["--tf", self.presets, "--tf-name", "CT-Bone", "--no-gradient-opacity"]
        common = ["--size", self.size, "--azimuth", "30", "--elevation", "15", "--frames", self.args.frames, "--json", *tf]
        if renderer == "octoray":
            cmd = ["/usr/bin/time", "-f", "RSS %M", self.bin / "octoray-render", store, "-o", self.out / "scale.png",
                   "--orbit", "0", *common]
        else:
            cmd = ["/usr/bin/time", "-f", "RSS %M", *self.vtk_prefix, self.bin / "vtk-peer", store, "--mapper",
                   renderer[4:], "-o", self.out / "scale.png", *common]
        log(f"scaling {renderer} {size}")
        try:
            r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=self.args.scale_timeout)
        except subprocess.TimeoutExpired:
            return {"size": size, "renderer": renderer, "note": f"over {self.args.scale_timeout} s"}
        rss = [int(l.split()[1]) for l in r.stderr.splitlines() if l.startswith("RSS ")]
        point = {"size": size, "renderer": renderer, "peakRssMiB": round(rss[-1] / 1024) if rss else None}
        if r.returncode != 0:
            lines = [l for l in r.stderr.splitlines() if l.strip() and not l.startswith("RSS ")]
            point["note"] = (lines[-1] if lines else f"exit {r.returncode}")[:200]
            return point
        report = json.loads(r.stdout[r.stdout.find("{"):])
        point["medianMs"] = report["medianMs"]
        point["firstMs"] = report.get("firstFrameMs")
        return point

    def main(self):
        scenes = self.args.scenes.split(",")
        modes = self.args.modes.split(",")
        for scene in scenes:
            stores = self.scene(scene)
            spacing = self.smallest_spacing(stores["uint16"])
            for mode in modes:
                for view in self.args.view_list:
                    truth = self.truth(scene, stores["uint16"], mode, view)
                    log(f"{scene} {mode} view {view}: our knobs")
                    self.sweep(scene, stores, mode, view, truth, spacing)
                    if not self.args.no_vtk and scene != "big":
                        log(f"{scene} {mode} view {view}: VTK")
                        self.vtk(scene, stores["uint16"], mode, view, truth, spacing)
                    self.write()
        if not self.args.no_scaling:
            self.scaling()
        self.write()
        log(f"rows in {self.out / 'rows.csv'}")
        failed = [r for r in self.rows if r["renderer"] == "octoray" and (r.get("note") or r.get("psnrDb") is None)]
        if failed:
            for r in failed:
                log(f"FAILED {r['scene']} {r['mode']} {r['knob']} {r['setting']}: {r.get('note')}")
            sys.exit(1)

    def write(self):
        with open(self.out / "rows.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS)
            w.writeheader()
            w.writerows(self.rows)
        with open(self.out / "truths.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["scene", "mode", "view", "converged", "stepMm", "lastChangeMax",
                                              "lastChangePsnrDb", "seconds", "leafBricks"])
            w.writeheader()
            w.writerows(self.truths)
        (self.out / "machine.json").write_text(json.dumps({
            "date": time.strftime("%Y-%m-%d %H:%M"), "uname": " ".join(os.uname()), "cpus": os.cpu_count(),
            "command": " ".join(sys.argv)}, indent=1))


def parse():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("build")
    p.add_argument("out")
    p.add_argument("--quick", action="store_true", help="seconds: 64x64, one view, one mode, few knobs (CI)")
    p.add_argument("--scenes", default="head,phantom512")
    p.add_argument("--modes", default="dvr-bone,dvr-soft,iso,mip")
    p.add_argument("--views", default="3",
                   help="how many of the views, or which (a comma list of indices, e.g. 1,2; one view: 2,)")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--frames", type=int, default=5)
    p.add_argument("--knobs", default="")
    p.add_argument("--big", default="", help="the 8 GiB phantom store, for the scene 'big' and scaling")
    p.add_argument("--big-zoom", type=float, default=6.0,
                   help="zoom of the scene 'big' (its truth reads the leaf bricks in view)")
    p.add_argument("--no-vtk", action="store_true")
    p.add_argument("--vtk-mappers", default="gpu,cpu", help="which of VTK's mappers run (gpu, cpu or both)")
    p.add_argument("--no-scaling", action="store_true")
    p.add_argument("--scale-timeout", type=int, default=900)
    args = p.parse_args()
    if "big" in args.scenes.split(",") and not args.big:
        p.error("the scene 'big' needs --big STORE")
    if "," in args.views:
        args.view_list = [int(v) for v in args.views.split(",") if v.strip()]
    else:
        args.view_list = list(range(int(args.views)))
    if not args.view_list:
        p.error(f"--views {args.views} selects no view: give a count (1 is view 0 alone) or a list such as 1,2")
    if any(v < 0 or v >= len(VIEWS) for v in args.view_list):
        p.error(f"--views: views are 0..{len(VIEWS) - 1}")
    if args.quick:
        args.scenes, args.modes, args.view_list, args.size, args.frames = "phantom64", "dvr-bone", [0], 64, 2
        args.knobs = args.knobs or "default,step,preintegration,image-adaptive"
    return args


if __name__ == "__main__":
    Bench(parse()).main()
