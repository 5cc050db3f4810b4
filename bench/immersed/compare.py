"""Compare raytile EXR render(s) of a scene with its Mitsuba reference.

    python compare.py RAYTILE.exr [MORE_SEEDS.exr ...] SCENE [--blocks 4] [--z-fail 5]

SCENE is a name (lamp_in_glass, ...) or a path to NAME.json. Prints, per channel: the image
means (raytile, reference), the ratio raytile/reference and its standard error, then for an
N x N grid of blocks (default 4 x 4: 16 x 16 pixels each at 64 x 64) the z-score
(block mean raytile - block mean reference) / standard error.

Noise: the reference's from its per-seed images (NAME_seeds.npy): per-pixel variance across
seeds, summed over the block (pixels are independent), divided by the number of seeds.
raytile's from its own seeds when 2 or more EXRs are given (same way); with ONE EXR raytile's
noise is unknown and the z-scores use the reference's noise only, so they overstate |z|
(give several seeds for a fair z, or --spp N to assume raytile's per-sample noise equals
Mitsuba's, a rough stand-in). Exit status 1 when |ratio - 1| > 2 % or any |z| > --z-fail.
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
# Scenes, references and renders go here (bench/out is not kept in git).
OUT = os.path.join(os.path.dirname(HERE), "out", "immersed")


def read_exr(path):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    return np.array(mi.Bitmap(path), dtype=np.float64)[:, :, :3]


def var_of_mean(stack):
    """stack: S x H x W x 3 independent renders -> per-pixel variance of their mean."""
    s = stack.shape[0]
    return stack.var(0, ddof=1) / s


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("args", nargs="+", help="EXR file(s), then the scene name")
    p.add_argument("--blocks", type=int, default=4)
    p.add_argument("--z-fail", type=float, default=5.0)
    p.add_argument("--spp", type=int, help="with ONE EXR: its spp; raytile's per-sample noise is "
                   "then assumed equal to Mitsuba's (rough: a stand-in, not a measurement)")
    a = p.parse_args()
    *exrs, scene = a.args
    if not exrs:
        p.error("give at least one EXR and a scene name")
    name = os.path.splitext(os.path.basename(scene))[0]
    ref_seeds = np.load(os.path.join(OUT, f"{name}_seeds.npy")).astype(np.float64)
    ref = ref_seeds.mean(0)
    rt_stack = np.stack([read_exr(e) for e in exrs])
    if rt_stack.shape[1:] != ref.shape:
        sys.exit(f"size mismatch: raytile {rt_stack.shape[1:]} vs reference {ref.shape}")
    rt = rt_stack.mean(0)
    bad_px = ~np.isfinite(rt).all(-1)
    if bad_px.any():
        print(f"WARNING: {bad_px.sum()} non-finite raytile pixels (set to 0)")
        rt = np.nan_to_num(rt, nan=0.0, posinf=0.0, neginf=0.0)
    h, w, _ = ref.shape
    n = h * w
    vref = var_of_mean(ref_seeds)
    ref_spp = 8192
    info = os.path.join(OUT, f"{name}_ref.json")
    if os.path.exists(info):
        import json
        ref_spp = json.load(open(info))["spp_per_seed"]
    if len(exrs) > 1:
        vrt = var_of_mean(rt_stack)
    elif a.spp:
        # one reference seed's per-pixel variance (ref_spp samples) scaled to a.spp samples
        vrt = ref_seeds.var(0, ddof=1) * ref_spp / a.spp
    else:
        vrt = np.zeros_like(vref)
    m_rt, m_ref = rt.reshape(-1, 3).mean(0), ref.reshape(-1, 3).mean(0)
    se_rt = np.sqrt(vrt.reshape(-1, 3).sum(0)) / n
    se_ref = np.sqrt(vref.reshape(-1, 3).sum(0)) / n
    ratio = m_rt / np.maximum(m_ref, 1e-30)
    se_ratio = ratio * np.sqrt((se_rt / np.maximum(m_rt, 1e-30)) ** 2 + (se_ref / m_ref) ** 2)
    print(f"scene {name}: {len(exrs)} raytile image(s), reference {ref_seeds.shape[0]} seeds, {w}x{h}")
    print(f"  mean raytile   R {m_rt[0]:.5f}  G {m_rt[1]:.5f}  B {m_rt[2]:.5f}"
          + (f"   (se {se_rt[0]:.5f} {se_rt[1]:.5f} {se_rt[2]:.5f})" if len(exrs) > 1 else "   (se unknown: one image)"))
    print(f"  mean reference R {m_ref[0]:.5f}  G {m_ref[1]:.5f}  B {m_ref[2]:.5f}"
          f"   (se {se_ref[0]:.5f} {se_ref[1]:.5f} {se_ref[2]:.5f})")
    print(f"  ratio raytile/ref  R {ratio[0]:.4f}  G {ratio[1]:.4f}  B {ratio[2]:.4f}"
          f"   (+- {se_ratio[0]:.4f} {se_ratio[1]:.4f} {se_ratio[2]:.4f})")
    nb = a.blocks
    bh, bw = h // nb, w // nb
    z = np.zeros((nb, nb, 3))
    rat = np.zeros((nb, nb, 3))
    for by in range(nb):
        for bx in range(nb):
            sl = (slice(by * bh, (by + 1) * bh), slice(bx * bw, (bx + 1) * bw))
            k = bh * bw
            d = rt[sl].reshape(-1, 3).mean(0) - ref[sl].reshape(-1, 3).mean(0)
            v = (vref[sl].reshape(-1, 3).sum(0) + vrt[sl].reshape(-1, 3).sum(0)) / k ** 2
            z[by, bx] = d / np.sqrt(v + 1e-30)
            rat[by, bx] = rt[sl].reshape(-1, 3).mean(0) / np.maximum(ref[sl].reshape(-1, 3).mean(0), 1e-30)
    note = ("" if len(exrs) > 1 else "  [raytile noise ASSUMED = Mitsuba's per sample]" if a.spp
            else "  [reference noise only: |z| overstated; give 2+ seeds or --spp]")
    print(f"  {nb}x{nb} blocks of {bw}x{bh} px, z = (raytile - ref) / se, rows top to bottom{note}")
    for by in range(nb):
        cells = "  ".join(f"{z[by, bx, 0]:+6.1f}{z[by, bx, 1]:+6.1f}{z[by, bx, 2]:+6.1f}"
                          for bx in range(nb))
        print(f"    z   {cells}")
    print("  block ratios raytile/ref (R G B):")
    for by in range(nb):
        cells = "  ".join(f"{rat[by, bx, 0]:5.2f} {rat[by, bx, 1]:5.2f} {rat[by, bx, 2]:5.2f}"
                          for bx in range(nb))
        print(f"    r   {cells}")
    zmax = np.abs(z).max()
    bad = np.abs(ratio - 1).max() > 0.02 or zmax > a.z_fail
    print(f"  max |z| {zmax:.2f} over {z.size} block-channels; max |ratio-1| "
          f"{np.abs(ratio - 1).max() * 100:.2f} %" + ("  FAIL" if bad else "  ok"))
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
