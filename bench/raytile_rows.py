"""Turn one raytile run into two result rows: render only, and the whole process.

    python bench/raytile_rows.py --stderr LOG --wall SECONDS --exr OUT.exr --spp N --threads T

raytile prints a summary on stderr such as `raytile: 256x256, 64 spp, path integrator, 1.23 s render (1.31 s total), 3.4 Msamples/s -> FILE`;
the render time is the first `N s` on the last line naming spp (else the last `N s`).
"""

import argparse
import json
import re
import sys

SECONDS = re.compile(r"([0-9]+(?:\.[0-9]+)?(?:[eE][-+]?[0-9]+)?)\s*s\b")


def render_seconds(text):
    """First `N s` on the last summary line (one naming spp), else the last in the text."""
    summary = [line for line in text.splitlines() if "spp" in line and SECONDS.search(line)]
    if summary:
        return float(SECONDS.findall(summary[-1])[0])
    matches = SECONDS.findall(text)
    return float(matches[-1]) if matches else None


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--stderr", required=True)
    p.add_argument("--wall", type=float, required=True)
    p.add_argument("--exr", required=True)
    p.add_argument("--spp", type=int, required=True)
    p.add_argument("--threads", type=int, required=True)
    args = p.parse_args()
    with open(args.stderr, errors="replace") as f:
        seconds = render_seconds(f.read())
    common = {"exr": args.exr, "spp": args.spp, "threads": args.threads}
    if seconds is None:
        print("raytile: no 'N s' render time on its stderr; using the process time",
              file=sys.stderr)
    else:
        print(json.dumps({"name": "raytile", "seconds": seconds, **common}))
    print(json.dumps({"name": "raytile (process)", "seconds": args.wall,
                      "note": "raytile (process): wall time of the whole process "
                              "(start-up, scene load, BVH build, render, EXR write).",
                      **common}))


if __name__ == "__main__":
    main()
