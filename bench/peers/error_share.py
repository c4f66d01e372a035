"""Where Tessera's and Mitsuba 3's errors are, per pixel, on one benchmark scene.

    VENV/bin/python error_share.py --tessera target/release/tessera [--scene spheres] [--spp 256]

Renders the scene with both renderers at two seeds each (Mitsuba's llvm_ad_rgb variant with
the Cook-style integrator of cook_integrator.py; `tessera render` with the seed written
into a copy of the scene), and against the converged reference in docs/references prints:
each run's RMSE; the share of the squared error held by the worst 0.1 % and 1 % of pixels;
the squared error in pixels brighter than --bright (sum of RGB in the reference) and
elsewhere; and the 40 x 40 tiles that hold the most of Tessera's error, with Mitsuba's
there. It tells noise that both renderers share (bright, heavy-tailed pixels) from error
one of them has alone.
"""
import argparse, os, subprocess, sys, tempfile
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import llvm_path  # noqa: E402
llvm_path.configure()
import numpy as np  # noqa: E402
import mitsuba as mi  # noqa: E402
import scenes  # noqa: E402
from mitsuba_vs import read_exr, seeded_scene, tessera_scene  # noqa: E402

def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tessera", required=True)
    p.add_argument("--scene", default="spheres")
    p.add_argument("--scene-dir", default="scenes")
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--bright", type=float, default=3.0)
    p.add_argument("--tile", type=int, default=40)
    p.add_argument("--refs", default=os.path.join(HERE, "..", "..", "docs", "references"))
    a = p.parse_args()
    mi.set_variant("llvm_ad_rgb")
    import cook_integrator
    cook_integrator.register()
    ref = read_exr(os.path.join(a.refs, f"{a.scene}_cook.exr"))
    scene = mi.load_dict(scenes.mitsuba_dict(a.scene, {"type": "cook", "max_depth": 8}, spp=a.spp))
    tmp = tempfile.mkdtemp()
    runs = {"tessera": [], "mitsuba": []}
    for seed in (1, 2):
        runs["mitsuba"].append(np.array(mi.render(scene, spp=a.spp, seed=seed), dtype=np.float64)[..., :3])
        out = os.path.join(tmp, f"t{seed}.exr")
        h, w = ref.shape[:2]
        with seeded_scene(tessera_scene(a.scene_dir, a.scene), seed) as seeded:
            cp = subprocess.run([a.tessera, "render", seeded, "-o", out, "--spp", str(a.spp), "--size", f"{w}x{h}"],
                                capture_output=True, text=True)
        if cp.returncode != 0:
            sys.exit(f"tessera render failed: {cp.stderr.strip()[-400:]}")
        runs["tessera"].append(read_exr(out))
    bright = ref.sum(-1) > a.bright
    print(f"{a.scene} at {a.spp} spp; {int(bright.sum())} pixels brighter than {a.bright} (RGB sum)")
    mean_se = {}
    for name, imgs in runs.items():
        se = [((im - ref) ** 2).sum(-1) for im in imgs]
        n = se[0].size
        rmse = ", ".join(f"{np.sqrt(s.sum() / (n * 3)):.5f}" for s in se)
        worst = np.sort(se[0].ravel())[::-1]
        print(f"{name:8} RMSE {rmse} | worst 0.1 % of pixels {worst[: n // 1000].sum() / se[0].sum():.2f} "
              f"of the squared error, worst 1 % {worst[: n // 100].sum() / se[0].sum():.2f} | "
              f"bright {se[0][bright].sum():.1f}, elsewhere {se[0][~bright].sum():.1f}")
        mean_se[name] = np.mean(se, 0)
    t, m = mean_se["tessera"], mean_se["mitsuba"]
    h, w = t.shape
    tiles = sorted(((t[y:y + a.tile, x:x + a.tile].sum(), m[y:y + a.tile, x:x + a.tile].sum(), x, y)
                    for y in range(0, h, a.tile) for x in range(0, w, a.tile)), reverse=True)
    print(f"squared error summed, mean of both seeds: Tessera {t.sum():.1f}, Mitsuba {m.sum():.1f}; "
          f"the {a.tile} x {a.tile} tiles with most of Tessera's (x, y from the top left):")
    for ts, ms, x, y in tiles[:8]:
        print(f"  ({x:4d}, {y:4d})  Tessera {ts:8.1f}  Mitsuba {ms:8.1f}")

if __name__ == "__main__":
    main()
