"""Compare renders against a converged reference; print the table and write Markdown.

    python bench/compare.py --rows ROWS.jsonl --reference REF.exr --reference-label TEXT \
        --markdown OUT.md [--title TEXT] [--note TEXT]...

ROWS.jsonl has one JSON object per renderer and round: name, exr, seconds, spp, threads, note
(rows of one name are rounds of a repeated run: their median seconds count).
For each: render seconds, samples/s, mean of each channel, the mean's offset from the
reference in standard errors (z), RMSE against the reference and the efficiency
1/(MSE x seconds) relative to the baseline row (raytile's render time if present), and
raytile's standing against the issue's goals: samples/s vs Mitsuba llvm_ad_rgb (>= 1.5x),
efficiency vs Cycles (>= 2x).
Exit status 1 if any channel's mean is more than FAIL_SIGMA standard errors off.
"""

import argparse
import json
import math
import sys

import numpy as np

WARN_SIGMA = 4.0
FAIL_SIGMA = 5.0
# (row, what to compare, raytile's goal as a multiple of that row's)
GOALS = [("mitsuba llvm_ad_rgb", "msamples_per_s", "samples/s", 1.5),
         ("cycles", "efficiency", "efficiency", 2.0)]


def read_exr(path):
    import mitsuba as mi
    if not mi.variant():
        mi.set_variant("scalar_rgb")
    img = np.array(mi.Bitmap(path), dtype=np.float64)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ValueError(f"{path}: expected an RGB image, got shape {img.shape}")
    return img[:, :, :3]


def stats(img, ref):
    """Channel means, z of each mean against the reference's, RMSE.

    The standard error comes from the difference image: with a box filter each pixel
    is an independent estimate, so std(img - ref) / sqrt(pixels) is the standard error
    of the mean difference, the reference's own (small) noise included.
    """
    if img.shape != ref.shape:
        raise ValueError(f"image shape {img.shape} differs from the reference's {ref.shape}")
    diff = (img - ref).reshape(-1, 3)
    n = diff.shape[0]
    se = diff.std(axis=0, ddof=1) / math.sqrt(n)
    z = diff.mean(axis=0) / np.maximum(se, 1e-30)
    return {"mean": img.reshape(-1, 3).mean(axis=0), "se": se, "z": z,
            "mse": float(np.mean(diff ** 2))}


def orientation_warning(name, img, ref):
    """A mirrored image keeps its means but not its pixels: say so if a flip fits better."""
    rmse = np.sqrt(np.mean((img - ref) ** 2))
    for label, flipped in (("upside down", img[::-1]), ("mirrored left-right", img[:, ::-1])):
        if np.sqrt(np.mean((flipped - ref) ** 2)) < 0.8 * rmse:
            print(f"WARNING: {name}: the image looks {label} against the reference",
                  file=sys.stderr)


def collapse(rows):
    """One row per renderer. A run with --repeat N gives N rows of each name (its rounds run
    the renderers in turn, so that a machine's drift touches them alike): keep the first row's
    fields with the median of their seconds, and every round's seconds in `times`."""
    by_name = {}
    for r in rows:
        if r["name"] not in by_name:
            by_name[r["name"]] = dict(r, times=[])
        by_name[r["name"]]["times"].append(float(r["seconds"]))
    for r in by_name.values():
        r["seconds"] = float(np.median(r["times"]))
    return list(by_name.values())


def rounds_note(rows):
    """The seconds of every round, where renderers ran more than once."""
    if all(len(r["times"]) < 2 for r in rows):
        return []
    times = "; ".join(f"{r['name']} " + ", ".join(f"{t:.3f}" for t in r["times"]) for r in rows)
    return [f"render seconds are the median of {max(len(r['times']) for r in rows)} rounds "
            f"(the renderers in turn in each round): {times}."]


def evaluate(rows, ref):
    for row in rows:
        img = read_exr(row["exr"])
        row.update(stats(img, ref))
        orientation_warning(row["name"], img, ref)
        pixels = ref.shape[0] * ref.shape[1]
        row["msamples_per_s"] = pixels * row["spp"] / row["seconds"] / 1e6
        row["efficiency"] = 1.0 / (row["mse"] * row["seconds"])
    base = next((r for r in rows if r["name"] == "raytile"), rows[0])
    for row in rows:
        row["relative_efficiency"] = row["efficiency"] / base["efficiency"]
        row["relative_speed"] = row["msamples_per_s"] / base["msamples_per_s"]
    return base["name"]


def goal_lines(rows):
    """raytile's samples/s and efficiency as multiples of the goal rows'."""
    by_name = {r["name"]: r for r in rows}
    raytile = by_name.get("raytile")
    if raytile is None:
        return []
    out = []
    for name, key, label, goal in GOALS:
        if name in by_name:
            ratio = raytile[key] / by_name[name][key]
            verdict = "met" if ratio >= goal else "not met"
            out.append(f"raytile's {label} = {ratio:.2f} × that of {name} "
                       f"(goal ≥ {goal:g}×: {verdict}).")
    return out


HEADER = ["renderer", "threads", "spp", "render s", "Msamples/s", "speed", "mean R", "mean G",
          "mean B", "max |z|", "RMSE", "efficiency"]


def table_rows(rows):
    out = []
    for r in rows:
        means = [f"{m:.5f} ± {s:.5f}" for m, s in zip(r["mean"], r["se"])]
        zmax = float(np.max(np.abs(r["z"])))
        flag = " **!!**" if zmax > WARN_SIGMA else ""
        out.append([r["name"], str(r["threads"]), str(r["spp"]), f"{r['seconds']:.3f}",
                    f"{r['msamples_per_s']:.3f}", f"{r['relative_speed']:.3f}", *means, f"{zmax:.2f}{flag}",
                    f"{math.sqrt(r['mse']):.5f}", f"{r['relative_efficiency']:.3f}"])
    return out


def markdown(rows, ref_label, ref_mean, base_name, notes, title=None):
    header = [h.replace("|", "\\|") for h in HEADER]
    lines = [f"## {title}", ""] if title else []
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(cells) + " |" for cells in table_rows(rows)]
    lines += ["", f"Reference: {ref_label}; its mean RGB "
              + ", ".join(f"{m:.5f}" for m in ref_mean) + ".",
              f"Speed = Msamples/s and efficiency = 1/(MSE × render seconds), both "
              f"relative to {base_name}'s.",
              *goal_lines(rows),
              "Means are ± one standard error; |z| = |mean − reference mean| / standard "
              f"error, worst channel (flagged **!!** above {WARN_SIGMA:g}σ, a failure above "
              f"{FAIL_SIGMA:g}σ)."]
    lines += [f"Note: {n}" for n in notes]
    return "\n".join(lines) + "\n"


def plain(rows):
    cells = [HEADER] + table_rows(rows)
    widths = [max(len(c[i]) for c in cells) for i in range(len(HEADER))]
    return "\n".join("  ".join(c[i].ljust(widths[i]) for i in range(len(c))) for c in cells)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rows", required=True)
    p.add_argument("--reference", required=True)
    p.add_argument("--reference-label", default="reference")
    p.add_argument("--markdown", required=True)
    p.add_argument("--note", action="append", default=[])
    p.add_argument("--title", help="heading of the Markdown table (the scene)")
    args = p.parse_args()
    with open(args.rows) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    if not rows:
        print("compare: no renders to compare", file=sys.stderr)
        return 1
    rows = collapse(rows)
    ref = read_exr(args.reference)
    base = evaluate(rows, ref)
    notes = args.note + [r["note"] for r in rows if r.get("note")] + rounds_note(rows)
    text = markdown(rows, args.reference_label, ref.reshape(-1, 3).mean(axis=0), base, notes,
                    args.title)
    with open(args.markdown, "w") as f:
        f.write(text)
    if args.title:
        print(args.title)
    print(plain(rows))
    print("\n".join(text.splitlines()[len(rows) + 2 + (2 if args.title else 0):]))
    worst = max(float(np.max(np.abs(r["z"]))) for r in rows)
    for r in rows:
        z = float(np.max(np.abs(r["z"])))
        if z > WARN_SIGMA:
            print(f"\n!!!!! {r['name']}: channel means differ from the reference by {z:.1f} "
                  f"standard errors (z per channel {np.round(r['z'], 2).tolist()}) !!!!!",
                  file=sys.stderr)
    return 1 if worst > FAIL_SIGMA else 0


if __name__ == "__main__":
    sys.exit(main())
