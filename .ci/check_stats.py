"""Checks a `pointray render --stats` file: the model covers a plausible share of the image."""
import json
import sys

path, lo, hi = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
with open(path) as f:
    s = json.load(f)
hit = s["hit_fraction"]
print(f"{path}: {s['points']} points, hit fraction {hit:.3f} (expected {lo}..{hi}), "
      f"{s['mrays_per_second']:.2f} Mrays/s, {s['splat_tests_per_ray']:.1f} splat tests/ray")
if not lo <= hit <= hi:
    sys.exit(f"{path}: hit fraction {hit:.3f} outside {lo}..{hi}")
if s["primary_rays"] <= 0 or s["rays"] < s["primary_rays"]:
    sys.exit(f"{path}: implausible ray counts")
