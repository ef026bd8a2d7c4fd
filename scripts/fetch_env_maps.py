#!/usr/bin/env python3
"""Fetches a few of Poly Haven's HDR panoramas (CC0) for --env-map, as the npm package
@pmndrs/assets carries them (512 x 256 OpenEXR, DWA-compressed, embedded as base64 in a
JavaScript module), and writes them as OUT/NAME.exr. Needs npm (no other download tool).

    python3 scripts/fetch_env_maps.py /tmp/maps park sunset
"""

import base64
import pathlib
import subprocess
import sys
import tarfile
import tempfile

PACKAGE = "@pmndrs/assets@1.7.0"


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    out = pathlib.Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(["npm", "pack", "--silent", PACKAGE], cwd=tmp, check=True, stdout=subprocess.DEVNULL)
        (tarball,) = pathlib.Path(tmp).glob("*.tgz")
        with tarfile.open(tarball) as tar:
            for name in sys.argv[2:]:
                try:
                    member = tar.extractfile(f"package/hdri/{name}.exr.js")
                except KeyError:
                    sys.exit(f"{PACKAGE} has no hdri/{name}.exr")
                text = member.read().decode()
                data = text[text.index("base64,") + len("base64,") : text.rindex("'")]
                (out / f"{name}.exr").write_bytes(base64.b64decode(data))
                print(out / f"{name}.exr")


if __name__ == "__main__":
    main()
