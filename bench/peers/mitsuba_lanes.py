"""What Mitsuba 3's SIMD lanes are worth to it, beside Tessera, in one run.

    VENV/bin/python mitsuba_lanes.py --tessera target/release/tessera [--scenes spheres,cornell]
        [--spp 16] [--depths 2,3,8] [--runs 3]

mitsuba_vs.py compares Tessera with Mitsuba's llvm_ad_rgb variant, which traces and shades
every sample of a launch in SIMD lanes (a JIT-compiled wavefront). Mitsuba also ships a
scalar_rgb variant: the same C++ code, one sample at a time, as Tessera traces. The Cook
integrator of mitsuba_vs.py is written in Python and crawls in scalar variants, so this
script times Mitsuba's own C++ `path` integrator at a few depths (depth 2 is direct light:
one emitter sample and one BSDF sample with MIS at the first hit, as Cook's transport does
on a diffuse surface), in both variants, each launch timed on its second and later calls
(the kernel compiled, the scene loaded), and Tessera's `render` of the scene at the same spp
as a whole process (scene load, coordinator and workers included), each with every core.

The figures are times, not errors: the path integrator follows diffuse bounces that Cook's
transport does not, and Tessera follows specular chains to depth 8 at every depth of this
table. What they show is how much of Mitsuba's speed is its lanes (scalar / llvm), and where
a tracer of one sample at a time stands against Mitsuba's (Tessera / scalar).
"""

import argparse, os, statistics, subprocess, sys, tempfile, time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import scenes  # noqa: E402

# Each variant in a process of its own: Mitsuba's variant is process-wide.
CHILD = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
import mitsuba as mi, drjit as dr
import scenes
variant, name, spp, depth, runs = sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6])
mi.set_variant(variant)
scene = mi.load_dict(scenes.mitsuba_dict(name, {"type": "path", "max_depth": depth}, spp=spp))
times = []
for k in range(runs + 1):
    t0 = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=k)
    dr.eval(img); dr.sync_thread()
    times.append(time.perf_counter() - t0)
print(" ".join(repr(t) for t in times[1:]))
"""


def mitsuba_times(variant, name, spp, depth, runs):
    cp = subprocess.run([sys.executable, "-c", CHILD, HERE, variant, name, str(spp), str(depth), str(runs)],
                        capture_output=True, text=True)
    if cp.returncode != 0:
        sys.exit(f"mitsuba {variant} failed: {cp.stderr.strip()[-400:]}")
    return [float(t) for t in cp.stdout.split()]


def tessera_times(binary, scene_file, spp, size, runs):
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "t.exr")
        for _ in range(runs):
            t0 = time.perf_counter()
            cp = subprocess.run([binary, "render", scene_file, "-o", out, "--spp", str(spp), "--size", size],
                                capture_output=True, text=True)
            times.append(time.perf_counter() - t0)
            if cp.returncode != 0:
                sys.exit(f"tessera render failed: {cp.stderr.strip()[-400:]}")
    return times


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tessera", required=True, help="path to the tessera binary")
    p.add_argument("--scene-dir", default="scenes", help="Tessera's scenes folder")
    p.add_argument("--scenes", default="spheres,cornell")
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--depths", default="2,3,8", help="the path integrator's max_depth values")
    p.add_argument("--runs", type=int, default=3, help="timed runs per renderer; medians are reported")
    a = p.parse_args()
    if a.spp < 1 or a.runs < 1:
        p.error("--spp and --runs must be at least 1")
    try:
        depths = [int(d) for d in a.depths.split(",")]
    except ValueError:
        p.error(f"--depths: expected integers separated by commas, got {a.depths!r}")
    print(f"{'scene':8} {'spp':>4} | {'Tessera s':>9} | {'depth':>5} {'llvm s':>7} {'scalar s':>8} "
          f"{'scalar/llvm':>11} {'Tessera/scalar':>14}")
    for name in a.scenes.split(","):
        if name not in scenes.SPEC:
            p.error(f"--scenes: no scene {name!r} (known: {', '.join(scenes.SPEC)})")
        cam = scenes.SPEC[name]["camera"]
        size = f"{cam['width']}x{cam['height']}"
        spec_file = scenes.SPEC[name].get("tessera_scene", f"scenes/{name}.toml")
        scene_file = os.path.join(a.scene_dir, os.path.relpath(spec_file, "scenes"))
        t = float(statistics.median(tessera_times(a.tessera, scene_file, a.spp, size, a.runs)))
        for depth in depths:
            llvm = float(statistics.median(mitsuba_times("llvm_ad_rgb", name, a.spp, depth, a.runs)))
            scalar = float(statistics.median(mitsuba_times("scalar_rgb", name, a.spp, depth, a.runs)))
            print(f"{name:8} {a.spp:>4} | {t:9.3f} | {depth:>5} {llvm:7.3f} {scalar:8.3f} "
                  f"{scalar / llvm:11.2f} {t / scalar:14.2f}", flush=True)


if __name__ == "__main__":
    main()
