"""Mitsuba 3 and Tessera side by side, in one run, on the benchmark scenes.

    VENV/bin/python mitsuba_vs.py --tessera target/release/tessera [--scenes cornell,spheres,terrain]
        [--spp 16,64,256] [--runs 3]

For each scene and spp: Mitsuba 3's llvm_ad_rgb variant with a Cook-style integrator
(cook_integrator.py: direct light with MIS at every hit, recursion along specular and
glossy lobes, stop at diffuse) -- timed on its second call, kernel compiled, scene load
excluded -- and `tessera render SCENE --spp N --size WxH` timed as a whole process (SCENE is
scenes/<scene>.toml, or the file scenes.py names: scenes/terrain/terrain.toml, whose mesh
`python3 scenes/generate-terrain.py` writes; WxH the reference's size).
Each run of either renderer has a seed of its own (1, 2, 3, ...). Both images are compared (RMSE over all pixels and linear RGB channels) with the
converged references in docs/references/<scene>_cook.exr (--refs). Prints one row per (scene, spp) and,
per scene, the time each needs to reach the error Tessera reaches at its largest spp
(interpolated on the log-log error curve): the ratio that matters to someone rendering.
A reference's own noise adds to every error measured against it, most to the smallest:
--also-refs OLD measures the same images against a second set too (an older, noisier
reference, say), so a change of reference shows apart from a change of renderer.
--reach measures instead of extrapolating: where Tessera's error at its largest spp is
below Mitsuba's, Mitsuba renders 4x the samples again and again (passes of at most 256 spp
averaged, each with its seed, timed in sum) until its error is at or below Tessera's, and
its time to that error is interpolated between the two measured points around it.
--noise 0.1,0.05 also renders Tessera with adaptive sampling (`tessera render --noise T
--spp CAP`: each pixel stops once its estimated relative error is below T; --noise-cap is
the most samples a pixel takes): one row per target, with the samples a pixel took on
average, and the time-to-equal-error ratios for each target's error. --noise-abs 0.05 does
the same with absolute targets (`tessera render --noise-abs T`: the error in the image's
linear units, what an RMSE counts). Mitsuba 3 has no adaptive sampler, so its rows are the
same uniform ones.
A reference's own noise is in every error measured against it: with --reach the measured
ratios are printed again with it taken out of every error in quadrature (sqrt(e^2 - r^2),
r the reference's noise: --ref-noise, by default the values scripts/compare-references.sh
uses for the repository's references).
Run it on an otherwise idle machine; both renderers use every core.
"""
import argparse, contextlib, math, os, re, subprocess, sys, tempfile, time
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import llvm_path  # noqa: E402
llvm_path.configure()
import numpy as np  # noqa: E402
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
import scenes  # noqa: E402

def render_mitsuba(scene, spp, seed):
    dr.sync_thread()
    t0 = time.perf_counter()
    img = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)
    dr.sync_thread()
    return img[..., :3], time.perf_counter() - t0

def load_mitsuba(name, spp):
    """Mitsuba's scene `name` with the Cook integrator, its kernel traced and compiled."""
    scene = mi.load_dict(scenes.mitsuba_dict(name, {"type": "cook", "max_depth": 8}, spp=spp))
    render_mitsuba(scene, spp, 0)
    return scene

def render_mitsuba_passes(scene, per, spp, seed):
    """Mitsuba at `spp` in passes of `per` (at most 256: one launch holds every sample's
    state, so a larger one would exhaust memory), averaged; the time is the passes' sum."""
    total, t = None, 0.0
    for k in range(spp // per):
        img, dt = render_mitsuba(scene, per, seed * 100_000 + k)
        total = img.astype(np.float64) if total is None else total + img
        t += dt
    return total / (spp // per), t

def time_between(err_target, rows):
    """Time to reach err_target, interpolated on log-log between the two rows around it."""
    rows = sorted(rows)
    for (t0, e0), (t1, e1) in zip(rows, rows[1:]):
        if e1 <= err_target <= e0:
            if e0 == e1:
                return t0
            f = (math.log(e0) - math.log(err_target)) / (math.log(e0) - math.log(e1))
            return float(math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0))))
    return None

def read_exr(path):
    return np.array(mi.Bitmap(path), dtype=np.float64)[..., :3]

def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))

def time_to(err_target, rows):
    """Time to reach err_target from (time, error) rows: a least-squares line through
    log error against log time (Monte Carlo error falls as a power of time)."""
    lt = np.log([t for t, _ in rows]); le = np.log([e for _, e in rows])
    slope, icept = np.polyfit(lt, le, 1)
    return float(np.exp((math.log(err_target) - icept) / slope))

def tessera_scene(scene_dir, name):
    """Tessera's file of scene `name`: scenes/<name>.toml, or where the spec says."""
    spec = scenes.SPEC.get(name, {})
    if "tessera_scene" in spec:
        return os.path.join(scene_dir, os.path.relpath(spec["tessera_scene"], "scenes"))
    return os.path.join(scene_dir, f"{name}.toml")

@contextlib.contextmanager
def seeded_scene(path, seed):
    """A copy of the scene file at `path` whose [render] table sets `seed`, beside the
    original (so that the paths of its assets, such as the terrain's OBJ, still resolve),
    under a name of its own; removed when the block ends, however it ends."""
    text = open(path).read()
    if "\n[render]\n" not in "\n" + text:
        sys.exit(f"{path}: no [render] table to set the seed in")
    if any(line.strip().startswith("seed") for line in text.splitlines()):
        sys.exit(f"{path}: already sets a seed")
    fd, out = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), prefix=f".seed{seed}-", suffix=".toml")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(("\n" + text).replace("\n[render]\n", f"\n[render]\nseed = {seed}\n", 1)[1:])
        yield out
    finally:
        os.remove(out)

def render_tessera(binary, scene, seed, out, size, extra):
    """`tessera render` of `scene` with `seed` at `size`, plus the arguments `extra`, timed
    as a whole process: (seconds, image, the last line it printed)."""
    # Tessera is deterministic: without a seed of its own per run, every run would be the
    # same image and the median of its errors one sample.
    with seeded_scene(scene, seed) as seeded:
        t0 = time.perf_counter()
        cp = subprocess.run([binary, "render", seeded, "-o", out, "--size", size, *extra],
                            capture_output=True, text=True)
        t = time.perf_counter() - t0
    if cp.returncode != 0:
        sys.exit(f"tessera render failed: {cp.stderr.strip()[-400:]}")
    lines = (cp.stdout + cp.stderr).strip().splitlines()
    return t, read_exr(out), lines[-1] if lines else ""

# The RMS noise of each reference in docs/references, as scripts/compare-references.sh
# takes it (measured when each reference was made, from its passes' spread).
REF_NOISE = {"spheres": 0.00976, "cornell": 0.00086, "terrain": 0.00019}

def without_noise(e, r):
    """Error e with a reference noise r taken out in quadrature."""
    return math.sqrt(e * e - r * r)

AVERAGE_SPP = re.compile(r"at ([0-9.]+) samples per pixel on average")
EVERY_PIXEL_SPP = re.compile(r", ([0-9]+) spp\)")

def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tessera", required=True, help="path to the tessera binary")
    p.add_argument("--scene-dir", default="scenes", help="Tessera's scenes folder (cornell.toml, spheres.toml, terrain/)")
    p.add_argument("--scenes", default="cornell,spheres")
    p.add_argument("--spp", default="16,64,256")
    p.add_argument("--runs", type=int, default=3, help="runs per renderer; medians are reported")
    p.add_argument("--refs", default=os.path.join(HERE, "..", "..", "docs", "references"),
                   help="folder with <scene>_cook.exr (default: the repository's docs/references)")
    p.add_argument("--also-refs", help="a second folder of references (an older one, say): the same images "
                   "are also measured against it where it has the scene, and the ratio printed for both")
    p.add_argument("--reach", action="store_true", help="render Mitsuba at 4x the samples until its error is "
                   "at or below Tessera's, and interpolate its time to that error instead of extrapolating")
    p.add_argument("--reach-limit", type=int, default=16384, help="the most spp --reach renders Mitsuba at")
    p.add_argument("--noise", help="also render Tessera adaptively to these relative noise targets, e.g. 0.1,0.05")
    p.add_argument("--noise-abs", help="also render Tessera adaptively to these absolute noise targets, e.g. 0.05")
    p.add_argument("--ref-noise", default=",".join(f"{k}={v}" for k, v in REF_NOISE.items()),
                   help="each reference's own RMS noise, scene=value,... (or 'none'), taken out of the errors "
                   "in quadrature for a second line of --reach's ratios")
    p.add_argument("--noise-cap", type=int, default=4096, help="the most samples a pixel takes with --noise and --noise-abs")
    a = p.parse_args()
    try:
        ref_noise = {} if a.ref_noise == "none" else {
            k: float(v) for k, v in (kv.split("=", 1) for kv in a.ref_noise.split(","))}
    except ValueError:
        p.error(f"--ref-noise: expected scene=value,... or none, got {a.ref_noise!r}")
    mi.set_variant("llvm_ad_rgb")
    import cook_integrator
    cook_integrator.register()
    tmp = tempfile.mkdtemp()
    print(f"{'scene':8} {'spp':>5} | {'mitsuba s':>9} {'Ms/s':>6} {'RMSE':>8} | {'tessera s':>9} {'Ms/s':>6} {'RMSE':>8} | T/M time")
    for name in a.scenes.split(","):
        ref = read_exr(os.path.join(a.refs, f"{name}_cook.exr"))
        h, w = ref.shape[:2]
        alt_path = a.also_refs and os.path.join(a.also_refs, f"{name}_cook.exr")
        alt = read_exr(alt_path) if alt_path and os.path.exists(alt_path) else None
        mrows, trows, malt, talt = [], [], [], []
        for spp in [int(s) for s in a.spp.split(",")]:
            scene = load_mitsuba(name, spp)
            mt, me, me2 = [], [], []
            for r in range(a.runs):
                img, t = render_mitsuba(scene, spp, 1 + r)
                mt.append(t); me.append(rmse(img, ref))
                if alt is not None:
                    me2.append(rmse(img, alt))
            tt, te, te2 = [], [], []
            for r in range(a.runs):
                # The reference's size: a scene may be compared smaller than its file says.
                t, img, _ = render_tessera(a.tessera, tessera_scene(a.scene_dir, name), 1 + r,
                                           os.path.join(tmp, f"{name}-{spp}.exr"), f"{w}x{h}", ["--spp", str(spp)])
                tt.append(t); te.append(rmse(img, ref))
                if alt is not None:
                    te2.append(rmse(img, alt))
            m_t, t_t = float(np.median(mt)), float(np.median(tt))
            m_e, t_e = float(np.median(me)), float(np.median(te))
            mrows.append((m_t, m_e)); trows.append((t_t, t_e))
            if alt is not None:
                malt.append((m_t, float(np.median(me2)))); talt.append((t_t, float(np.median(te2))))
            print(f"{name:8} {spp:5d} | {m_t:9.3f} {w*h*spp/m_t/1e6:6.2f} {m_e:8.5f} | "
                  f"{t_t:9.3f} {w*h*spp/t_t/1e6:6.2f} {t_e:8.5f} | {t_t/m_t:5.2f}", flush=True)
        ratios = [("uniform", trows[-1])]
        targets = [("--noise", "noise", float(n)) for n in a.noise.split(",")] if a.noise else []
        targets += [("--noise-abs", "noise-abs", float(n)) for n in a.noise_abs.split(",")] if a.noise_abs else []
        for flag, label, target_noise in targets:
            tt, te, avg = [], [], []
            for r in range(a.runs):
                t, img, line = render_tessera(a.tessera, tessera_scene(a.scene_dir, name), 1 + r,
                                              os.path.join(tmp, f"{name}-noise.exr"), f"{w}x{h}",
                                              [flag, str(target_noise), "--spp", str(a.noise_cap)])
                # Where no pixel met the target before the cap, every pixel took the cap.
                m = AVERAGE_SPP.search(line) or EVERY_PIXEL_SPP.search(line)
                if m is None:
                    sys.exit(f"tessera render: no sample count in its last line: {line!r}")
                tt.append(t); te.append(rmse(img, ref)); avg.append(float(m.group(1)))
            t_t, t_e, t_spp = float(np.median(tt)), float(np.median(te)), float(np.median(avg))
            print(f"{name:8} {'':5} | {label} {target_noise:<5g} (Tessera only, adaptive: {t_spp:.1f} spp on average, "
                  f"at most {a.noise_cap}) | {t_t:9.3f} {w*h*t_spp/t_t/1e6:6.2f} {t_e:8.5f} |", flush=True)
            ratios.append((f"{label} {target_noise:g}", (t_t, t_e)))
        for how, (t_t, target) in ratios:
            m_need = time_to(target, mrows)
            print(f"{name} ({how}): to reach RMSE {target:.5f} Tessera takes {t_t:.2f} s, Mitsuba ~{m_need:.2f} s"
                  f" -> time ratio at equal error T/M = {t_t/m_need:.2f}", flush=True)
        if a.reach:
            target = min(e for _, (_, e) in ratios)
            spp, rows = int(a.spp.split(",")[-1]), list(mrows)
            while min(e for _, e in rows) > target and spp * 4 <= a.reach_limit:
                spp *= 4
                mt, me = [], []
                per = min(spp, 256)
                passes = load_mitsuba(name, per)
                for r in range(a.runs):
                    img, t = render_mitsuba_passes(passes, per, spp, 1 + r)
                    mt.append(t); me.append(rmse(img, ref))
                m_t, m_e = float(np.median(mt)), float(np.median(me))
                rows.append((m_t, m_e))
                print(f"{name:8} {spp:5d} | {m_t:9.3f} {w*h*spp/m_t/1e6:6.2f} {m_e:8.5f} | (Mitsuba only, --reach)",
                      flush=True)
            for how, (t_t, target) in ratios:
                m_meas = time_between(target, rows)
                if m_meas is None:
                    print(f"{name} ({how}): Mitsuba did not reach RMSE {target:.5f} by {spp} spp (--reach-limit)",
                          flush=True)
                else:
                    print(f"{name} ({how}): measured, Mitsuba reaches RMSE {target:.5f} in ~{m_meas:.2f} s "
                          f"(interpolated between its measured points) -> T/M = {t_t/m_meas:.2f}", flush=True)
                r = ref_noise.get(name)
                # Within a tenth of the reference's noise an error is mostly that noise, and
                # what is left of it is not measured.
                if not r or target <= 1.1 * r:
                    continue
                clean = [(t, without_noise(e, r)) for t, e in rows if e > 1.1 * r]
                m_clean = time_between(without_noise(target, r), clean)
                if m_clean:
                    print(f"{name} ({how}): the same, the reference's noise {r} taken out of every error in "
                          f"quadrature: Mitsuba ~{m_clean:.2f} s -> T/M = {t_t/m_clean:.2f}", flush=True)
        if alt is not None:
            errs = ", ".join(f"{m:.5f}/{t:.5f}" for (_, m), (_, t) in zip(malt, talt))
            m_alt = time_to(talt[-1][1], malt)
            print(f"{name} against {alt_path}: RMSE Mitsuba/Tessera {errs}; to reach RMSE {talt[-1][1]:.5f}"
                  f" Mitsuba ~{m_alt:.2f} s -> T/M = {talt[-1][0]/m_alt:.2f}", flush=True)

if __name__ == "__main__":
    main()
