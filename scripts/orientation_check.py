#!/usr/bin/env python3
"""How many of `pointray prepare`'s normals point against a mesh's own normals.

    python3 scripts/orientation_check.py MESH.ply [--pointray BIN]

MESH is an ASCII or binary little-endian PLY with vertices and faces. `pointray prepare` ignores
the faces and orients its PCA normals by itself; this compares each prepared normal with the
area-weighted normal of the faces around the same vertex (matched by position) and prints the
share that point the other way. Pure Python: meant for meshes of up to a few hundred thousand
vertices.
"""
import argparse, os, struct, subprocess, sys, tempfile

FMT = {"char": "b", "uchar": "B", "int8": "b", "uint8": "B", "short": "h", "ushort": "H", "int16": "h",
       "uint16": "H", "int": "i", "uint": "I", "int32": "i", "uint32": "I", "float": "f", "float32": "f",
       "double": "d", "float64": "d"}


def read_ply(path):
    """(elements, data): each element's property list, and its rows as lists of values."""
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline().decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        body = f.read()
    fmt = next(l.split()[1] for l in header if l.startswith("format"))
    elements = []
    for l in header:
        p = l.split()
        if p[0] == "element":
            elements.append((p[1], int(p[2]), []))
        elif p[0] == "property":
            elements[-1][2].append(p[1:])
    if fmt not in ("ascii", "binary_little_endian"):
        sys.exit(f"{path}: {fmt} PLY is not supported here")
    reader = Ascii(body) if fmt == "ascii" else Binary(body)
    data = {}
    for name, count, props in elements:
        rows = []
        for _ in range(count):
            row = []
            for prop in props:
                if prop[0] == "list":
                    n = int(reader.scalar(prop[1]))
                    row.append([int(reader.scalar(prop[2])) for _ in range(n)])
                else:
                    row.append(reader.scalar(prop[0]))
            rows.append(row)
        data[name] = rows
    return elements, data


class Ascii:
    """Values of an ASCII PLY body, one after another."""

    def __init__(self, body):
        self.tokens, self.at = body.split(), 0

    def scalar(self, kind):
        self.at += 1
        return float(self.tokens[self.at - 1])


class Binary:
    """Values of a binary little-endian PLY body, one after another."""

    def __init__(self, body):
        self.body, self.at = body, 0

    def scalar(self, kind):
        f = "<" + FMT[kind]
        (v,) = struct.unpack_from(f, self.body, self.at)
        self.at += struct.calcsize(f)
        return v


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mesh")
    ap.add_argument("--pointray", default=os.path.join(os.path.dirname(__file__), "..", "target", "release", "pointray"))
    a = ap.parse_args()
    elements, mesh = read_ply(a.mesh)
    names = [p[-1] for p in next(e for e in elements if e[0] == "vertex")[2]]
    ix, iy, iz = names.index("x"), names.index("y"), names.index("z")
    verts = [(r[ix], r[iy], r[iz]) for r in mesh["vertex"]]
    normals = [[0.0, 0.0, 0.0] for _ in verts]
    for face in mesh["face"]:
        idx = face[0]
        for k in range(1, len(idx) - 1):  # fan triangulation; the cross product is twice the area
            a_, b_, c_ = idx[0], idx[k], idx[k + 1]
            n = cross(sub(verts[b_], verts[a_]), sub(verts[c_], verts[a_]))
            for v in (a_, b_, c_):
                for j in range(3):
                    normals[v][j] += n[j]
    # Matched by position within a millionth of the model's size (the prepared cloud stores
    # positions as offsets from an origin, which may move them by an ulp), through a grid.
    lo = [min(v[k] for v in verts) for k in range(3)]
    size = max(max(v[k] for v in verts) - lo[k] for k in range(3))
    tol, cell = 1e-6 * size, 1e-4 * size
    key = lambda p: tuple(int((p[k] - lo[k]) // cell) for k in range(3))
    grid = {}
    for v, n in zip(verts, normals):
        grid.setdefault(key(v), []).append((v, n))

    def mesh_normal(p):
        c = key(p)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for v, n in grid.get((c[0] + dx, c[1] + dy, c[2] + dz), ()):
                        if max(abs(v[k] - p[k]) for k in range(3)) <= tol:
                            return n
        return None
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "prepared.ply")
        subprocess.run([a.pointray, "-q", "prepare", a.mesh, "-o", out], check=True)
        elements, prepared = read_ply(out)
    names = [p[-1] for p in next(e for e in elements if e[0] == "vertex")[2]]
    cols = [names.index(c) for c in ("x", "y", "z", "nx", "ny", "nz")]
    against = matched = 0
    for row in prepared["vertex"]:
        x, y, z, nx, ny, nz = (row[c] for c in cols)
        m = mesh_normal((x, y, z))
        if m is None or m == [0.0, 0.0, 0.0]:
            continue
        matched += 1
        against += (nx * m[0] + ny * m[1] + nz * m[2]) < 0
    print(f"{a.mesh}: {against} of {matched} normals ({100.0 * against / max(matched, 1):.2f} %) point against the mesh's")


if __name__ == "__main__":
    main()
