"""A converged reference of a benchmark scene, made with Mitsuba 3 and the Cook integrator.

    VENV/bin/python make_reference.py terrain [--passes 16] [--spp 256] [--out docs/references]

Renders the scene of scenes.py PASSES times at SPP samples per pixel (seeds 1000, 1001, ...:
never the seeds mitsuba_vs.py compares with), writes their mean as <out>/<scene>_cook.exr
(32-bit floats, linear RGB: a half float's rounding, about 7·10⁻⁵ RMS at the terrain's
brightness, would be a third of a 256-pass reference's noise) and prints the
reference's own noise, the RMSE its mean still has (the spread of the passes over
sqrt(PASSES)): an error measured against it cannot fall below that.
"""
import argparse, os, sys, time
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import llvm_path  # noqa: E402
llvm_path.configure()
import numpy as np  # noqa: E402
import mitsuba as mi  # noqa: E402
import scenes  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", choices=scenes.SCENE_NAMES)
    p.add_argument("--passes", type=int, default=16)
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--out", default=os.path.join(HERE, "..", "..", "docs", "references"))
    a = p.parse_args()
    if a.passes < 2 or a.spp < 1:
        sys.exit("--passes must be at least 2 and --spp at least 1")
    mi.set_variant("llvm_ad_rgb")
    import cook_integrator
    cook_integrator.register()
    scene = mi.load_dict(scenes.mitsuba_dict(a.scene, {"type": "cook", "max_depth": 8}, spp=a.spp))
    t0 = time.perf_counter()
    passes = []
    for k in range(a.passes):
        passes.append(np.array(mi.render(scene, spp=a.spp, seed=1000 + k), dtype=np.float64)[..., :3])
        print(f"pass {k + 1}/{a.passes} done, {time.perf_counter() - t0:.0f} s", flush=True)
    stack = np.stack(passes)
    mean = stack.mean(0)
    # The variance of the mean, per pixel and channel, from the spread of the passes.
    noise = float(np.sqrt(np.mean(stack.var(0, ddof=1) / a.passes)))
    os.makedirs(a.out, exist_ok=True)
    path = os.path.join(a.out, f"{a.scene}_cook.exr")
    mi.Bitmap(mean.astype(np.float32)).convert(component_format=mi.Struct.Type.Float32).write(path)
    print(f"wrote {path}: {a.passes} x {a.spp} spp, {mean.shape[1]}x{mean.shape[0]}; "
          f"its own noise (RMSE of the mean) {noise:.5f}; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
