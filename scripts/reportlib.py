"""What the comparison scripts (kdtree_compare.py, surface_compare.py) share: running pointray,
the run's header, the JSON lines, and the hand-written discussion kept across regenerations."""

import argparse
import datetime
import json
import os
import subprocess


def run(cmd):
    """Runs `cmd` (any items, made strings) and returns its stdout; raises with its stderr."""
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({p.returncode}): {p.stderr.strip()[-2000:]}")
    return p.stdout


def header(**settings):
    """Date, commit (marked dirty if tracked files differ from it), cores and the settings."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                           text=True).stdout.strip()
    return {"date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "commit": commit + ("+dirty" if dirty else ""), "cores": os.cpu_count(), **settings}


def write_jsonl(path, header, records):
    with open(path, "w") as f:
        for rec in [header] + records:
            f.write(json.dumps(rec) + "\n")


def read_jsonl(path):
    """(header, records) as `write_jsonl` wrote them."""
    lines = [json.loads(line) for line in open(path)]
    return lines[0], lines[1:]


def write_report(path, lines):
    """Writes the generated `lines`, then the '## Discussion' of the report already at `path`."""
    keep = ""
    if os.path.exists(path):
        text = open(path).read()
        i = text.find("\n## Discussion")
        keep = text[i:] if i >= 0 else ""
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n" + keep)


def arguments(doc, cache, models, size, out, extra=lambda ap: None):
    """The scripts' common command line (`extra` adds a script's own options), parsed; plus
    `a.jsonl`, the JSON lines beside the report."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pointray", required=True)
    ap.add_argument("--data", default="../shared/data")
    ap.add_argument("--cache", default=cache)
    ap.add_argument("--models", default=",".join(models))
    ap.add_argument("--size", type=int, default=size)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=out)
    ap.add_argument("--report-only", action="store_true", help="rewrite the report from the JSON lines")
    extra(ap)
    a = ap.parse_args()
    a.jsonl = os.path.splitext(a.out)[0] + "-results.jsonl"
    return a


def find(records, **fields):
    """The first record whose fields have these values, or None."""
    return next((r for r in records if all(r.get(x) == v for x, v in fields.items())), None)
